//! A reader of Rust source good enough for the layout checks: tokens without comments and
//! strings, the crate's module tree, the paths each file uses (through `use` trees and inline
//! paths), resolved to the file that defines them.

use std::collections::BTreeMap;
use std::path::Path;

use super::*;
/// A token of Rust source with comments, strings and character literals removed.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Tok {
    Ident(String),
    PathSep,
    Punct(char),
}

/// Tokens with their 1-based line numbers. Comments (nested block comments too), string, byte
/// string, raw string and character literals are skipped; lifetimes are kept as punctuation and
/// an identifier.
pub(super) fn tokens(src: &str) -> Vec<(Tok, usize)> {
    let s: Vec<char> = src.chars().collect();
    let mut out = Vec::new();
    let (mut i, mut line) = (0, 1);
    let n = s.len();
    let at = |i: usize| s.get(i).copied().unwrap_or('\0');
    while i < n {
        let c = s[i];
        if c == '\n' {
            line += 1;
            i += 1;
        } else if c.is_whitespace() {
            i += 1;
        } else if c == '/' && at(i + 1) == '/' {
            while i < n && s[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && at(i + 1) == '*' {
            let mut depth = 0;
            while i < n {
                if s[i] == '/' && at(i + 1) == '*' {
                    depth += 1;
                    i += 2;
                } else if s[i] == '*' && at(i + 1) == '/' {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    if s[i] == '\n' {
                        line += 1;
                    }
                    i += 1;
                }
            }
        } else if c == '"' || ((c == 'b' || c == 'c') && at(i + 1) == '"') {
            // A plain string: up to the next unescaped quote.
            i += if c == '"' { 1 } else { 2 };
            while i < n && s[i] != '"' {
                if s[i] == '\\' {
                    i += 1;
                }
                if at(i) == '\n' {
                    line += 1;
                }
                i += 1;
            }
            i += 1;
        } else if (c == 'r'
            && (at(i + 1) == '"' || (at(i + 1) == '#' && matches!(at(i + 2), '"' | '#'))))
            || (c == 'b' && at(i + 1) == 'r' && matches!(at(i + 2), '"' | '#'))
        {
            // A raw string: r#*" ... "#*.
            i += if c == 'b' { 2 } else { 1 };
            let mut hashes = 0;
            while at(i) == '#' {
                hashes += 1;
                i += 1;
            }
            i += 1; // the opening quote
            while i < n {
                if s[i] == '"' && (1..=hashes).all(|k| at(i + k) == '#') {
                    i += 1 + hashes;
                    break;
                }
                if s[i] == '\n' {
                    line += 1;
                }
                i += 1;
            }
        } else if c == '\'' || (c == 'b' && at(i + 1) == '\'') {
            let start = if c == 'b' { i + 1 } else { i };
            if at(start + 1) == '\\' {
                // An escaped character literal.
                i = start + 2;
                while i < n && s[i] != '\'' {
                    i += 1;
                }
                i += 1;
            } else if at(start + 2) == '\'' {
                i = start + 3; // 'x'
            } else {
                out.push((Tok::Punct('\''), line)); // a lifetime
                i = start + 1;
            }
        } else if c.is_alphabetic() || c == '_' {
            let begin = i;
            while i < n && (s[i].is_alphanumeric() || s[i] == '_') {
                i += 1;
            }
            let word: String = s[begin..i].iter().collect();
            // Raw identifiers `r#name`.
            if word == "r" && at(i) == '#' && (at(i + 1).is_alphabetic() || at(i + 1) == '_') {
                continue;
            }
            out.push((Tok::Ident(word), line));
        } else if c.is_ascii_digit() {
            while i < n && (s[i].is_alphanumeric() || s[i] == '_' || s[i] == '.') {
                if s[i] == '.' && !at(i + 1).is_ascii_digit() {
                    break;
                }
                i += 1;
            }
        } else if c == ':' && at(i + 1) == ':' {
            out.push((Tok::PathSep, line));
            i += 2;
        } else {
            out.push((Tok::Punct(c), line));
            i += 1;
        }
    }
    out
}

/// Which crate of the package a file belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Krate {
    Lib,
    Bin,
}

/// A file module: its crate and module path (`["nn", "train"]`).
pub(super) type ModKey = (Krate, Vec<String>);

/// The module tree of the package: every file reached from `src/lib.rs` and `src/main.rs`
/// through `mod NAME;` declarations.
pub(super) struct Tree {
    /// Module → file (relative to the repository, e.g. `src/nn/train.rs`).
    pub(super) files: BTreeMap<ModKey, String>,
}

impl Tree {
    pub(super) fn load() -> Self {
        let mut files = BTreeMap::new();
        for (krate, root) in [(Krate::Lib, "src/lib.rs"), (Krate::Bin, "src/main.rs")] {
            let mut todo = vec![(Vec::<String>::new(), root.to_string())];
            while let Some((path, file)) = todo.pop() {
                let text = read(&file);
                // Children of `a/mod.rs`, `lib.rs` and `main.rs` live beside them; those of
                // `a/b.rs` in `a/b/`.
                let dir = {
                    let p = Path::new(&file);
                    let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or("");
                    let parent = p.parent().unwrap_or(Path::new(""));
                    if matches!(stem, "mod" | "lib" | "main") {
                        parent.to_path_buf()
                    } else {
                        parent.join(stem)
                    }
                };
                for child in declared_modules(&text) {
                    let a = dir.join(format!("{child}.rs"));
                    let b = dir.join(&child).join("mod.rs");
                    let found = [a, b].into_iter().find(|p| repo().join(p).is_file());
                    if let Some(f) = found {
                        let mut p = path.clone();
                        p.push(child);
                        todo.push((p, f.to_string_lossy().into_owned()));
                    }
                }
                files.insert((krate, path), file);
            }
        }
        Self { files }
    }

    /// The deepest file module that is a prefix of `path` in `krate`, and how many segments of
    /// `path` it covers.
    pub(super) fn deepest(&self, krate: Krate, path: &[String]) -> Option<(ModKey, usize)> {
        (0..=path.len()).rev().find_map(|k| {
            let key = (krate, path[..k].to_vec());
            self.files.contains_key(&key).then_some((key, k))
        })
    }
}

/// A path a file uses, made absolute: the crate and its segments (a trailing `*` for a glob).
#[derive(Clone, Debug)]
pub(super) struct UsedPath {
    pub(super) krate: Krate,
    pub(super) segments: Vec<String>,
    pub(super) line: usize,
    /// As written, for messages.
    pub(super) text: String,
    /// From a `pub use` at the file's top level (a re-export).
    pub(super) reexport: bool,
}

/// Reads a use tree starting at `toks[i]`; pushes every leaf path (prefix + segments) and
/// returns the index after the tree.
pub(super) fn use_tree(
    toks: &[(Tok, usize)],
    mut i: usize,
    prefix: &[String],
    out: &mut Vec<(Vec<String>, Option<String>)>,
) -> usize {
    let mut path = prefix.to_vec();
    if toks.get(i).map(|t| &t.0) == Some(&Tok::PathSep) {
        i += 1; // a leading `::`
    }
    loop {
        match toks.get(i).map(|t| &t.0) {
            Some(Tok::Ident(w)) => {
                path.push(w.clone());
                i += 1;
                if toks.get(i).map(|t| &t.0) == Some(&Tok::PathSep) {
                    i += 1;
                    continue;
                }
                // `as alias`
                let mut alias = None;
                if toks.get(i).map(|t| &t.0) == Some(&Tok::Ident("as".into())) {
                    if let Some((Tok::Ident(a), _)) = toks.get(i + 1) {
                        alias = Some(a.clone());
                    }
                    i += 2;
                }
                out.push((path, alias));
                return i;
            }
            Some(Tok::Punct('*')) => {
                path.push("*".into());
                out.push((path, None));
                return i + 1;
            }
            Some(Tok::Punct('{')) => {
                i += 1;
                loop {
                    match toks.get(i).map(|t| &t.0) {
                        Some(Tok::Punct('}')) => return i + 1,
                        Some(Tok::Punct(',')) => i += 1,
                        None => return i,
                        _ => {
                            let before = i;
                            i = use_tree(toks, i, &path, out);
                            if i == before {
                                i += 1;
                            }
                        }
                    }
                }
            }
            _ => {
                if !path.is_empty() && path.len() > prefix.len() {
                    out.push((path, None));
                }
                return i;
            }
        }
    }
}

/// Every path into the package's own modules that a file uses (in `use` declarations and in
/// code), made absolute, and the names it re-exports at its top level (`pub use`).
pub(super) fn used_paths(
    tree: &Tree,
    key: &ModKey,
    src: &str,
) -> (Vec<UsedPath>, BTreeMap<String, UsedPath>) {
    let toks = tokens(src);
    let (krate, file_path) = (key.0, &key.1);
    // Inline modules (`mod tests { .. }`) move `super` and `self`.
    let mut inline: Vec<String> = Vec::new();
    let mut braces: Vec<bool> = Vec::new();
    let mut pending_mod: Option<String> = None;
    let mut used = Vec::new();
    let mut reexports = BTreeMap::new();
    // Absolute form of a path written in the current scope; `None` for other crates.
    let absolute = |inline: &[String], segs: &[String]| -> Option<(Krate, Vec<String>)> {
        let mut here: Vec<String> = file_path.clone();
        here.extend(inline.iter().cloned());
        let first = segs.first()?;
        match first.as_str() {
            "crate" => Some((krate, segs[1..].to_vec())),
            "compend" => Some((Krate::Lib, segs[1..].to_vec())),
            "self" => {
                here.extend(segs[1..].iter().cloned());
                Some((krate, here))
            }
            "super" => {
                let ups = segs.iter().take_while(|s| *s == "super").count();
                if ups > here.len() {
                    return None;
                }
                here.truncate(here.len() - ups);
                here.extend(segs[ups..].iter().cloned());
                Some((krate, here))
            }
            // A relative path to a child module of the current module (2018 paths).
            name => {
                let mut child = here.clone();
                child.push(name.to_string());
                if inline.is_empty() && tree.files.contains_key(&(krate, child)) {
                    here.extend(segs.iter().cloned());
                    Some((krate, here))
                } else {
                    None
                }
            }
        }
    };
    let mut i = 0;
    while i < toks.len() {
        let (tok, line) = (&toks[i].0, toks[i].1);
        match tok {
            Tok::Ident(w) if w == "mod" => {
                if let Some((Tok::Ident(name), _)) = toks.get(i + 1) {
                    pending_mod = Some(name.clone());
                    i += 2;
                    continue;
                }
            }
            Tok::Punct('{') => {
                let is_mod = pending_mod.take();
                braces.push(is_mod.is_some());
                if let Some(m) = is_mod {
                    inline.push(m);
                }
            }
            Tok::Punct('}') => {
                let closes_a_module = braces.pop() == Some(true);
                if closes_a_module {
                    inline.pop();
                }
            }
            Tok::Punct(';') => pending_mod = None,
            Tok::Ident(w) if w == "use" => {
                // `pub use` / `pub(crate) use` at the top level re-exports.
                let public = i >= 1
                    && (toks[i - 1].0 == Tok::Ident("pub".into())
                        || (toks[i - 1].0 == Tok::Punct(')')
                            && toks[..i].iter().rev().nth(3).map(|t| &t.0)
                                == Some(&Tok::Ident("pub".into()))));
                let mut leaves = Vec::new();
                let end = use_tree(&toks, i + 1, &[], &mut leaves);
                for (segs, alias) in leaves {
                    if let Some((k, abs)) = absolute(&inline, &segs) {
                        let text = segs.join("::");
                        let u = UsedPath {
                            krate: k,
                            segments: abs,
                            line,
                            text: format!("use {text}"),
                            reexport: public && inline.is_empty(),
                        };
                        if u.reexport {
                            let name = alias.clone().or_else(|| segs.last().cloned());
                            if let Some(name) = name.filter(|n| n != "*" && n != "self") {
                                reexports.insert(name, u.clone());
                            }
                        }
                        used.push(u);
                    }
                }
                i = end.max(i + 1);
                continue;
            }
            Tok::Ident(w)
                if matches!(w.as_str(), "crate" | "super" | "compend")
                    && toks.get(i + 1).map(|t| &t.0) == Some(&Tok::PathSep)
                    // Not the tail of a longer path (`x::crate` cannot occur; `a::super` can't).
                    && (i == 0 || toks[i - 1].0 != Tok::PathSep) =>
            {
                let mut segs = vec![w.clone()];
                let mut j = i + 1;
                while toks.get(j).map(|t| &t.0) == Some(&Tok::PathSep) {
                    match toks.get(j + 1).map(|t| &t.0) {
                        Some(Tok::Ident(s)) => {
                            segs.push(s.clone());
                            j += 2;
                        }
                        _ => break,
                    }
                }
                if let Some((k, abs)) = absolute(&inline, &segs) {
                    used.push(UsedPath {
                        krate: k,
                        segments: abs,
                        line,
                        text: segs.join("::"),
                        reexport: false,
                    });
                }
                i = j;
                continue;
            }
            _ => {}
        }
        i += 1;
    }
    (used, reexports)
}

/// The file a used path lands in: the deepest file module on the path, followed through that
/// module's re-exports (`pub use child::Item`) when the next segment is one.
pub(super) fn resolve(
    tree: &Tree,
    reexports: &BTreeMap<ModKey, BTreeMap<String, UsedPath>>,
    krate: Krate,
    segments: &[String],
    depth: usize,
) -> Option<ModKey> {
    let segs: Vec<String> = segments.iter().filter(|s| *s != "*").cloned().collect();
    let (key, covered) = tree.deepest(krate, &segs)?;
    if depth < 8
        && let Some(next) = segs.get(covered)
        && let Some(target) = reexports.get(&key).and_then(|m| m.get(next))
    {
        let mut rest = target.segments.clone();
        rest.extend(segs[covered + 1..].iter().cloned());
        if let Some(k) = resolve(tree, reexports, target.krate, &rest, depth + 1) {
            return Some(k);
        }
    }
    Some(key)
}
