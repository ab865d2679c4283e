//! The source tree agrees with its floor plan (docs/architecture.md, "Layers"): the module map in
//! `src/lib.rs` and the module table of the architecture document name exactly the modules that
//! exist, no two files of `src/` import each other in a circle, and nothing cites a design file
//! outside the repository. Every test reads the tree at test time and lists every problem it
//! finds, not just the first.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

mod graph;
mod rust;

use graph::*;
use rust::*;

pub(super) fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub(super) fn read(rel: &str) -> String {
    let path = repo().join(rel);
    fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: cannot read: {e}", path.display()))
}

pub(super) fn is_ident(s: &str) -> bool {
    let mut chars = s.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Whether `src/NAME.rs` or `src/NAME/mod.rs` exists.
pub(super) fn top_module_exists(name: &str) -> bool {
    let src = repo().join("src");
    src.join(format!("{name}.rs")).is_file() || src.join(name).join("mod.rs").is_file()
}

/// Names of the `mod NAME;` declarations (any visibility) at the top level of a Rust file.
pub(super) fn declared_modules(text: &str) -> BTreeSet<String> {
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
pub(super) fn lib_map_modules() -> BTreeSet<String> {
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
pub(super) fn doc_table_modules() -> Result<BTreeSet<String>, String> {
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

/// (b) No import circle between files of `src/`: a file that uses another through `use`,
/// `crate::`/`super::`/`compend::` paths depends on the file of the deepest module on that
/// path (through re-exports to where the item is defined). A module using its own submodules is
/// no circle (those edges are left out); a submodule that uses a sibling which uses it back is.
/// Edges file → file of `src/`, each with the first use that makes it (line, text); a
/// module's uses of its own descendants are left out.
fn file_edges(tree: &Tree) -> Edges {
    let sources: BTreeMap<ModKey, String> = tree
        .files
        .iter()
        .map(|(k, f)| (k.clone(), read(f)))
        .collect();
    let mut uses = BTreeMap::new();
    let mut reexports = BTreeMap::new();
    for (key, src) in &sources {
        let (u, r) = used_paths(tree, key, src);
        uses.insert(key.clone(), u);
        reexports.insert(key.clone(), r);
    }
    let mut edges: Edges = BTreeMap::new();
    for (from, list) in &uses {
        for u in list {
            let Some(to) = resolve(tree, &reexports, u.krate, &u.segments, 0) else {
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
    edges
}

#[test]
fn no_import_circle_between_files() {
    let tree = Tree::load();
    let edges = file_edges(&tree);
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

/// The shell of the library (docs/architecture.md, "Layers"): the modules that talk to devices.
const SHELL: [&[&str]; 10] = [
    &["gpu"],
    &["window"],
    &["media"],
    &["source"],
    &["camera"],
    &["player"],
    &["output"],
    &["rigs"],
    &["config"],
    &["service"],
];

/// (b') The pure core never uses the shell: no file of a core module of the library imports a
/// file of a shell module.
#[test]
fn core_modules_never_use_the_shell() {
    let tree = Tree::load();
    let edges = file_edges(&tree);
    let shell = |k: &ModKey| {
        k.0 == Krate::Lib
            && SHELL.iter().any(|s| {
                k.1.starts_with(&s.iter().map(|x| x.to_string()).collect::<Vec<_>>())
            })
    };
    let core = |k: &ModKey| k.0 == Krate::Lib && !k.1.is_empty() && !shell(k);
    let mut found = Vec::new();
    for (from, tos) in &edges {
        for (to, (line, how)) in tos {
            if core(from) && shell(to) {
                found.push(format!(
                    "{} → {}  ({}:{line}: {how})",
                    tree.files[from], tree.files[to], tree.files[from]
                ));
            }
        }
    }
    assert!(
        found.is_empty(),
        "core files use the shell (docs/architecture.md, \"Layers\"):\n  {}",
        found.join("\n  ")
    );
}

// ---------------------------------------------------------------------------------------------
// (c) No citation of a design file outside the repository.

/// Every file under `dir` (recursively).
pub(super) fn files_under(dir: &Path, out: &mut Vec<PathBuf>) {
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

/// The library's layers, lowest first (docs/architecture.md, "Layers"). A module may use the
/// modules of its own layer and of the layers below it, never one above, and no two modules use
/// each other in a circle, directly or through others.
const LAYERS: &[(&str, &[&str])] = &[
    (
        "foundations",
        &[
            "size",
            "error",
            "files",
            "background",
            "raster",
            "pngio",
            "resize",
            "sample",
            "filter",
            "metrics",
            "morph",
            "device",
            "tensors",
        ],
    ),
    (
        "geometry and data",
        &["fov", "warp", "patterns", "slgrid", "dataset"],
    ),
    (
        "models",
        &[
            "linear", "joint", "failure", "nn", "method", "record", "model", "fit",
        ],
    ),
    ("the per-frame path", &["playback"]),
    ("calibration", &["calibrate"]),
    ("the virtual rig", &["rig"]),
    ("shell: devices", &["gpu", "camera", "media"]),
    ("shell: sources", &["source"]),
    ("shell: the playback loop", &["player"]),
    ("shell: screens", &["window", "output"]),
    ("shell: the service", &["config", "rigs", "service"]),
];

/// Edges between the library's top-level modules (a file of module `a` uses a path into module
/// `b`, as written: a re-export does not hide whom a file names), each with its first use.
fn module_edges(tree: &Tree) -> BTreeMap<String, BTreeMap<String, (String, usize, String)>> {
    let mut edges: BTreeMap<String, BTreeMap<String, (String, usize, String)>> = BTreeMap::new();
    for (key, file) in &tree.files {
        let (Krate::Lib, path) = key else { continue };
        let Some(from) = path.first() else { continue };
        let (used, _) = used_paths(tree, key, &read(file));
        for u in used {
            let Some(to) = u.segments.first() else {
                continue;
            };
            if u.krate != Krate::Lib || to == from || !top_module_exists(to) {
                continue;
            }
            edges
                .entry(from.clone())
                .or_default()
                .entry(to.clone())
                .or_insert((file.clone(), u.line, u.text.clone()));
        }
    }
    edges
}

/// (b'') The layer order between modules, not only between files: every module of the library
/// is in one layer of [`LAYERS`], uses no module of a higher layer, and no modules use each
/// other in a circle.
#[test]
fn modules_keep_their_layer_order() {
    let tree = Tree::load();
    let declared = declared_modules(&read("src/lib.rs"));
    let mut problems = Vec::new();
    let layer_of = |m: &str| LAYERS.iter().position(|(_, ms)| ms.contains(&m));
    for m in &declared {
        if layer_of(m).is_none() {
            problems.push(format!(
                "module `{m}` is in no layer of tests/layout LAYERS"
            ));
        }
    }
    let edges = module_edges(&tree);
    for (from, tos) in &edges {
        for (to, (file, line, how)) in tos {
            if let (Some(a), Some(b)) = (layer_of(from), layer_of(to))
                && b > a
            {
                problems.push(format!(
                    "`{from}` ({}) uses `{to}` ({}), a higher layer: {file}:{line}: {how}",
                    LAYERS[a].0, LAYERS[b].0
                ));
            }
        }
    }
    // Circles between modules: strongly connected components of the module graph.
    let keys: BTreeMap<String, ModKey> = declared
        .iter()
        .map(|m| (m.clone(), (Krate::Lib, vec![m.clone()])))
        .collect();
    let mut as_files: Edges = BTreeMap::new();
    for (from, tos) in &edges {
        for (to, (_, line, how)) in tos {
            if let (Some(a), Some(b)) = (keys.get(from), keys.get(to)) {
                as_files
                    .entry(a.clone())
                    .or_default()
                    .insert(b.clone(), (*line, how.clone()));
            }
        }
    }
    let modules = Tree {
        files: keys.values().map(|k| (k.clone(), k.1[0].clone())).collect(),
    };
    for scc in strongly_connected(&modules, &as_files) {
        let walk: Vec<String> = shortest_cycle(&scc, &as_files)
            .iter()
            .map(|k| k.1[0].clone())
            .collect();
        let steps: Vec<String> = walk
            .windows(2)
            .map(|w| {
                let (file, line, how) = &edges[&w[0]][&w[1]];
                format!("{} → {} ({file}:{line}: {how})", w[0], w[1])
            })
            .collect();
        problems.push(format!(
            "modules in a circle: {}\n      {}",
            walk.join(" → "),
            steps.join("\n      ")
        ));
    }
    assert!(
        problems.is_empty(),
        "the modules break their layer order (docs/architecture.md, \"Layers\"), {} problem(s):\n  {}",
        problems.len(),
        problems.join("\n  ")
    );
}
