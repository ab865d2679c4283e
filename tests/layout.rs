//! The source tree agrees with its floor plan (docs/architecture.md, "Layers"): the module map in
//! `src/lib.rs` and the module table of the architecture document name exactly the modules that
//! exist, no two files of `src/` import each other in a circle, and nothing cites a design file
//! outside the repository. Every test reads the tree at test time and lists every problem it
//! finds, not just the first.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    let path = repo().join(rel);
    fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: cannot read: {e}", path.display()))
}

fn is_ident(s: &str) -> bool {
    let mut chars = s.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Whether `src/NAME.rs` or `src/NAME/mod.rs` exists.
fn top_module_exists(name: &str) -> bool {
    let src = repo().join("src");
    src.join(format!("{name}.rs")).is_file() || src.join(name).join("mod.rs").is_file()
}

/// Names of the `mod NAME;` declarations (any visibility) at the top level of a Rust file.
fn declared_modules(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for line in text.lines() {
        let mut line = line.trim();
        // Attributes on the same line (`#[cfg(...)] pub mod x;`).
        while line.starts_with("#[") {
            match line.find(']') {
                Some(i) => line = line[i + 1..].trim_start(),
                None => break,
            }
        }
        let rest = line
            .strip_prefix("pub ")
            .or_else(|| {
                line.strip_prefix("pub(")
                    .and_then(|r| r.split_once(')'))
                    .map(|(_, r)| r.trim_start())
            })
            .unwrap_or(line);
        if let Some(name) = rest
            .strip_prefix("mod ")
            .and_then(|r| r.trim().strip_suffix(';'))
            .map(str::trim)
            && is_ident(name)
        {
            out.insert(name.to_string());
        }
    }
    out
}

/// The modules the `//!` map of `src/lib.rs` names: its intra-doc links "[`NAME`]".
fn lib_map_modules() -> BTreeSet<String> {
    let lib = read("src/lib.rs");
    let mut out = BTreeSet::new();
    for line in lib.lines().filter(|l| l.trim_start().starts_with("//!")) {
        let mut rest = line;
        while let Some(i) = rest.find("[`") {
            rest = &rest[i + 2..];
            if let Some(j) = rest.find("`]") {
                let name = &rest[..j];
                if is_ident(name) {
                    out.insert(name.to_string());
                }
                rest = &rest[j + 2..];
            }
        }
    }
    out
}

/// The modules of the table in docs/architecture.md's "Layers" section: the first backticked
/// name in the first cell of each row of the table whose header starts with `| module`.
fn doc_table_modules() -> Result<BTreeSet<String>, String> {
    let doc = read("docs/architecture.md");
    let section: Vec<&str> = doc
        .lines()
        .skip_while(|l| l.trim() != "## Layers")
        .skip(1)
        .take_while(|l| !l.starts_with("## "))
        .collect();
    if section.is_empty() {
        return Err("docs/architecture.md has no \"## Layers\" section".into());
    }
    let Some(header) = section
        .iter()
        .position(|l| l.trim_start().starts_with("| module"))
    else {
        return Err(
            "docs/architecture.md, \"Layers\": no module table (a table whose header starts with \
             `| module`)"
                .into(),
        );
    };
    let mut out = BTreeSet::new();
    for row in section
        .iter()
        .skip(header + 2)
        .take_while(|l| l.trim_start().starts_with('|'))
    {
        let cell = row.trim_start().trim_start_matches('|');
        let cell = cell.split('|').next().unwrap_or("");
        match cell.split('`').nth(1) {
            Some(name) if is_ident(name) => {
                out.insert(name.to_string());
            }
            _ => {
                return Err(format!(
                    "docs/architecture.md, module table: row without a `module` name: {row}"
                ));
            }
        }
    }
    if out.is_empty() {
        return Err("docs/architecture.md, \"Layers\": the module table has no rows".into());
    }
    Ok(out)
}

/// (a) Every module the map and the table name exists, and every module `src/lib.rs` declares
/// (and every module the binary's `src/main.rs` declares) is named in both (the binary's only in
/// the table: the library's map has no links into the binary).
#[test]
fn module_map_and_table_match_the_tree() {
    let lib = read("src/lib.rs");
    let declared = declared_modules(&lib);
    let binary = declared_modules(&read("src/main.rs"));
    let map = lib_map_modules();
    let mut problems = Vec::new();
    let table = doc_table_modules().unwrap_or_else(|e| {
        problems.push(e);
        BTreeSet::new()
    });
    for (where_, names) in [
        ("the module map of src/lib.rs", &map),
        (
            "the module table of docs/architecture.md (\"Layers\")",
            &table,
        ),
    ] {
        for name in names {
            if !top_module_exists(name) {
                problems.push(format!(
                    "{where_} names `{name}`, but neither src/{name}.rs nor src/{name}/mod.rs exists"
                ));
            }
        }
    }
    for name in &declared {
        if !map.contains(name) {
            problems.push(format!(
                "src/lib.rs declares `pub mod {name};`, but its module map (the `//!` lines) does \
                 not name it as [`{name}`]"
            ));
        }
        if !table.is_empty() && !table.contains(name) {
            problems.push(format!(
                "src/lib.rs declares `pub mod {name};`, but the module table of \
                 docs/architecture.md (\"Layers\") has no row for `{name}`"
            ));
        }
    }
    for name in &binary {
        if !table.is_empty() && !table.contains(name) {
            problems.push(format!(
                "src/main.rs declares `mod {name};`, but the module table of docs/architecture.md \
                 (\"Layers\") has no row for `{name}`"
            ));
        }
    }
    for name in map.iter().chain(&table) {
        if top_module_exists(name) && !declared.contains(name) && !binary.contains(name) {
            problems.push(format!(
                "`{name}` is named in the map or the table and src/{name} exists, but neither \
                 src/lib.rs nor src/main.rs declares it"
            ));
        }
    }
    problems.dedup();
    assert!(
        problems.is_empty(),
        "the module map and the tree disagree ({} problem(s)):\n  {}",
        problems.len(),
        problems.join("\n  ")
    );
}

// ---------------------------------------------------------------------------------------------
// (b) Import circles between files.

/// A token of Rust source with comments, strings and character literals removed.
#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    PathSep,
    Punct(char),
}

/// Tokens with their 1-based line numbers. Comments (nested block comments too), string, byte
/// string, raw string and character literals are skipped; lifetimes are kept as punctuation and
/// an identifier.
fn tokens(src: &str) -> Vec<(Tok, usize)> {
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
enum Krate {
    Lib,
    Bin,
}

/// A file module: its crate and module path (`["nn", "train"]`).
type ModKey = (Krate, Vec<String>);

/// The module tree of the package: every file reached from `src/lib.rs` and `src/main.rs`
/// through `mod NAME;` declarations.
struct Tree {
    /// Module → file (relative to the repository, e.g. `src/nn/train.rs`).
    files: BTreeMap<ModKey, String>,
}

impl Tree {
    fn load() -> Self {
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
    fn deepest(&self, krate: Krate, path: &[String]) -> Option<(ModKey, usize)> {
        (0..=path.len()).rev().find_map(|k| {
            let key = (krate, path[..k].to_vec());
            self.files.contains_key(&key).then_some((key, k))
        })
    }
}

/// A path a file uses, made absolute: the crate and its segments (a trailing `*` for a glob).
#[derive(Clone, Debug)]
struct UsedPath {
    krate: Krate,
    segments: Vec<String>,
    line: usize,
    /// As written, for messages.
    text: String,
    /// From a `pub use` at the file's top level (a re-export).
    reexport: bool,
}

/// Reads a use tree starting at `toks[i]`; pushes every leaf path (prefix + segments) and
/// returns the index after the tree.
fn use_tree(
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
fn used_paths(tree: &Tree, key: &ModKey, src: &str) -> (Vec<UsedPath>, BTreeMap<String, UsedPath>) {
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
                if braces.pop() == Some(true) {
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
fn resolve(
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

/// (b) No import circle between files of `src/`: a file that uses another through `use`,
/// `crate::`/`super::`/`compend::` paths depends on the file of the deepest module on that
/// path (through re-exports to where the item is defined). A module using its own submodules is
/// no circle (those edges are left out); a submodule that uses a sibling which uses it back is.
#[test]
fn no_import_circle_between_files() {
    let tree = Tree::load();
    let sources: BTreeMap<ModKey, String> = tree
        .files
        .iter()
        .map(|(k, f)| (k.clone(), read(f)))
        .collect();
    let mut uses = BTreeMap::new();
    let mut reexports = BTreeMap::new();
    for (key, src) in &sources {
        let (u, r) = used_paths(&tree, key, src);
        uses.insert(key.clone(), u);
        reexports.insert(key.clone(), r);
    }
    // Edges file → file, each with the first use that makes it.
    let mut edges: BTreeMap<ModKey, BTreeMap<ModKey, (usize, String)>> = BTreeMap::new();
    for (from, list) in &uses {
        for u in list {
            let Some(to) = resolve(&tree, &reexports, u.krate, &u.segments, 0) else {
                continue;
            };
            let descendant = to.0 == from.0 && to.1.starts_with(&from.1);
            if to == *from || descendant {
                continue;
            }
            edges
                .entry(from.clone())
                .or_default()
                .entry(to)
                .or_insert((u.line, u.text.clone()));
        }
    }
    let cycles = strongly_connected(&tree, &edges);
    if cycles.is_empty() {
        return;
    }
    let file = |k: &ModKey| tree.files[k].clone();
    let mut report = Vec::new();
    for scc in &cycles {
        let names: Vec<String> = scc.iter().map(file).collect();
        let mut text = format!("circle among {}:", names.join(", "));
        for w in shortest_cycle(scc, &edges).windows(2) {
            let (line, how) = &edges[&w[0]][&w[1]];
            text.push_str(&format!(
                "\n    {} → {}  ({}:{line}: {how})",
                file(&w[0]),
                file(&w[1]),
                file(&w[0])
            ));
        }
        let members: BTreeSet<&ModKey> = scc.iter().collect();
        let inside: Vec<String> =
            scc.iter()
                .flat_map(|a| {
                    edges[a].iter().filter(|(b, _)| members.contains(b)).map(
                        move |(b, (line, how))| {
                            format!("{} → {}  ({}:{line}: {how})", file(a), file(b), file(a))
                        },
                    )
                })
                .collect();
        if inside.len() > 2 {
            text.push_str("\n    every import inside this circle:");
            for e in inside {
                text.push_str(&format!("\n      {e}"));
            }
        }
        report.push(text);
    }
    panic!(
        "{} import circle(s) between files of src/ (docs/architecture.md, \"Layers\"):\n  {}",
        report.len(),
        report.join("\n  ")
    );
}

type Edges = BTreeMap<ModKey, BTreeMap<ModKey, (usize, String)>>;

/// The strongly connected components of more than one file (Tarjan).
fn strongly_connected(tree: &Tree, edges: &Edges) -> Vec<Vec<ModKey>> {
    struct State<'a> {
        edges: &'a Edges,
        index: BTreeMap<ModKey, usize>,
        low: BTreeMap<ModKey, usize>,
        stack: Vec<ModKey>,
        on_stack: BTreeSet<ModKey>,
        next: usize,
        out: Vec<Vec<ModKey>>,
    }
    fn visit(st: &mut State, v: &ModKey) {
        st.index.insert(v.clone(), st.next);
        st.low.insert(v.clone(), st.next);
        st.next += 1;
        st.stack.push(v.clone());
        st.on_stack.insert(v.clone());
        let targets: Vec<ModKey> = st
            .edges
            .get(v)
            .map(|m| m.keys().cloned().collect())
            .unwrap_or_default();
        for w in &targets {
            if !st.index.contains_key(w) {
                visit(st, w);
                let lw = st.low[w];
                let lv = st.low.get_mut(v).expect("visited");
                *lv = (*lv).min(lw);
            } else if st.on_stack.contains(w) {
                let iw = st.index[w];
                let lv = st.low.get_mut(v).expect("visited");
                *lv = (*lv).min(iw);
            }
        }
        if st.low[v] == st.index[v] {
            let mut scc = Vec::new();
            while let Some(w) = st.stack.pop() {
                st.on_stack.remove(&w);
                let done = w == *v;
                scc.push(w);
                if done {
                    break;
                }
            }
            if scc.len() > 1 {
                scc.sort();
                st.out.push(scc);
            }
        }
    }
    let mut st = State {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in tree.files.keys() {
        if !st.index.contains_key(v) {
            visit(&mut st, v);
        }
    }
    st.out.sort();
    st.out
}

/// A shortest cycle through the first file of a strongly connected component, as a closed walk
/// (first = last), by breadth-first search inside the component.
fn shortest_cycle(scc: &[ModKey], edges: &Edges) -> Vec<ModKey> {
    let members: BTreeSet<&ModKey> = scc.iter().collect();
    let start = &scc[0];
    let mut prev: BTreeMap<ModKey, ModKey> = BTreeMap::new();
    let mut queue = std::collections::VecDeque::from([start.clone()]);
    while let Some(v) = queue.pop_front() {
        for w in edges.get(&v).into_iter().flat_map(|m| m.keys()) {
            if !members.contains(w) {
                continue;
            }
            if w == start {
                let mut walk = vec![v.clone()];
                let mut cur = v.clone();
                while cur != *start {
                    cur = prev[&cur].clone();
                    walk.push(cur.clone());
                }
                walk.reverse();
                walk.push(start.clone());
                return walk;
            }
            if !prev.contains_key(w) && w != start {
                prev.insert(w.clone(), v.clone());
                queue.push_back(w.clone());
            }
        }
    }
    vec![start.clone()]
}

// ---------------------------------------------------------------------------------------------
// (c) No citation of a design file outside the repository.

/// Every file under `dir` (recursively).
fn files_under(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            files_under(&path, out);
        } else {
            out.push(path);
        }
    }
}

/// (c) No file under src/, tests/, scripts/ or shaders/, nor README.md, cites the design file
/// that lived outside the repository: docs/architecture.md is the design document.
#[test]
fn no_citation_of_an_outside_design_file() {
    // Spelled in two pieces so that this file does not cite it itself.
    let needle = format!("{}.md", "DESIGN");
    let root = repo();
    let mut files = vec![root.join("README.md")];
    for dir in ["src", "tests", "scripts", "shaders"] {
        files_under(&root.join(dir), &mut files);
    }
    files.sort();
    let mut hits = Vec::new();
    for path in &files {
        let Ok(bytes) = fs::read(path) else { continue };
        let text = String::from_utf8_lossy(&bytes);
        for (n, line) in text.lines().enumerate() {
            if line.contains(&needle) {
                let rel = path.strip_prefix(&root).unwrap_or(path);
                hits.push(format!("{}:{}: {}", rel.display(), n + 1, line.trim()));
            }
        }
    }
    assert!(
        hits.is_empty(),
        "{} line(s) cite {needle}, which is not in the repository; cite the matching section of \
         docs/architecture.md instead:\n  {}",
        hits.len(),
        hits.join("\n  ")
    );
}

/// The tokenizer keeps paths in code and drops them in comments, strings and characters, and
/// the use-tree reader expands groups.
#[test]
fn layout_checker_reads_paths_as_rust_does() {
    let src = "use crate::a::{b::C, d as e, f::*};\n// crate::x::y\n/* crate::z */ let s = \"crate::q\";\nlet c = '\"'; fn f<'a>() { crate::g::h(); super::i::J }";
    let names: Vec<String> = tokens(src)
        .into_iter()
        .filter_map(|(t, _)| match t {
            Tok::Ident(w) => Some(w),
            _ => None,
        })
        .collect();
    for gone in ["x", "y", "z", "q"] {
        assert!(
            !names.contains(&gone.to_string()),
            "{gone} should be skipped: {names:?}"
        );
    }
    for kept in ["g", "h", "i", "J", "a"] {
        assert!(
            names.contains(&kept.to_string()),
            "{kept} should be kept: {names:?}"
        );
    }
    let toks = tokens("crate::a::{b::C, d as e, f::*};");
    let mut leaves = Vec::new();
    use_tree(&toks, 0, &[], &mut leaves);
    let paths: Vec<String> = leaves.iter().map(|(p, _)| p.join("::")).collect();
    assert_eq!(paths, ["crate::a::b::C", "crate::a::d", "crate::a::f::*"]);
    assert_eq!(leaves[1].1.as_deref(), Some("e"));
    let decl = declared_modules(
        "pub mod a;\nmod b;\n#[cfg(test)]\nmod tests {\n}\npub(crate) mod c;\n#[cfg(unix)] pub mod d;\n",
    );
    assert_eq!(decl.into_iter().collect::<Vec<_>>(), ["a", "b", "c", "d"]);
}
