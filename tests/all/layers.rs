//! ARCHITECTURE.md's layer table, kept: every path a library module names (`crate::`,
//! `super::`, `self::`, a child module's name, and `crate` aliases such as `use crate as
//! root;`, grouped imports included) resolves to a module its row allows; the library never
//! names clap or indicatif; only `src/sim/physics.rs` names rapier; and the module graph has no
//! circle: an import between two modules counts between the children of their nearest common
//! ancestor (files of one folder, or the folders that hold them), and an import between a
//! module and its own ancestor counts too (a folder's `mod.rs` that re-exports or uses its
//! children must not be what they import: `use super::Thing` in `lerobot/read.rs`, with
//! `lerobot/mod.rs` using `read`, is a circle). Test modules (`#[cfg(test)]` and below) are
//! left out of the circles: their `super::` is their own file.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

type Module = Vec<String>;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// module -> allowed imports, from the "## Layers" table.
fn table() -> BTreeMap<String, BTreeSet<String>> {
    let text = std::fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let section = text.split("## Layers").nth(1).expect("a Layers section");
    section
        .lines()
        .skip_while(|l| !l.starts_with("| module"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|line| {
            let cells: Vec<&str> = line.trim_matches('|').split('|').map(str::trim).collect();
            let allowed = cells[1]
                .split(',')
                .map(|m| m.trim().to_string())
                .filter(|m| !m.is_empty());
            (cells[0].to_string(), allowed.collect())
        })
        .collect()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("dir") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The code of a file without its comments (doc comments may name other layers).
fn code(path: &Path) -> String {
    std::fs::read_to_string(path)
        .expect("source")
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The module path of a file under `src` ("collect::run"; a folder's mod.rs is the folder).
fn module_of(relative: &Path) -> Module {
    let mut parts: Module = relative
        .with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    parts
}

/// The library's modules (not the binary, not lib.rs) and their code.
fn library(src: &Path) -> BTreeMap<Module, String> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    files
        .iter()
        .map(|f| (module_of(f.strip_prefix(src).expect("under src")), code(f)))
        .filter(|(m, _)| m.first().is_some_and(|c| c != "bin" && c != "lib"))
        .collect()
}

/// A module's code without its test module (by convention the file's end, from
/// `#[cfg(test)]`), whose `super::` means the file itself.
fn without_tests(code: &str) -> &str {
    code.find("#[cfg(test)]").map_or(code, |at| &code[..at])
}

fn is_word(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The paths after `at` in `text`: `a::b` gives one, `{a::b, c::{d}}` one per item (their
/// first segments are what resolution needs).
fn paths_after(text: &str) -> Vec<Vec<String>> {
    let head: String = text
        .chars()
        .take_while(|c| is_word(*c) || *c == ':')
        .collect();
    let mut segments: Vec<String> = head
        .split("::")
        .filter(|s| !s.is_empty())
        .map(String::from)
        .collect();
    let rest = &text[head.len()..];
    if !rest.starts_with('{') {
        return vec![segments];
    }
    // A group: split its items at the top level.
    let (mut depth, mut item, mut items) = (0, String::new(), Vec::new());
    for c in rest[1..].chars() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => break,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                items.push(std::mem::take(&mut item));
                continue;
            }
            _ => {}
        }
        item.push(c);
    }
    items.push(item);
    let base = std::mem::take(&mut segments);
    items
        .iter()
        .map(|item| item.trim())
        .filter(|item| !item.is_empty())
        .flat_map(|item| {
            paths_after(item).into_iter().map(|tail| {
                let mut full = base.clone();
                full.extend(tail.into_iter().filter(|s| s != "self"));
                full
            })
        })
        .collect()
}

/// Every module path `text` (the code of `module`) names, made absolute: `crate::`, names
/// `crate` is aliased to, `self::`, `super::` (repeated) and a path that starts with one of
/// `module`'s children (`use read::Source;` in a folder's `mod.rs`), each resolved to the
/// longest prefix that is a module of `modules`.
fn references(module: &Module, text: &str, modules: &BTreeMap<Module, String>) -> Vec<Module> {
    let mut roots: Vec<String> = vec!["crate".into()];
    for (i, _) in text.match_indices("crate as ") {
        let alias: String = text[i + 9..].chars().take_while(|c| is_word(*c)).collect();
        roots.push(alias);
    }
    let mut found = Vec::new();
    let mut starts: Vec<(usize, Module, usize)> = Vec::new();
    for name in roots.iter().map(String::as_str).chain(["self", "super"]) {
        let prefix = format!("{name}::");
        for (i, _) in text.match_indices(&prefix) {
            if text[..i].ends_with(|c: char| is_word(c) || c == ':') {
                continue;
            }
            let base: Module = match name {
                "self" => module.clone(),
                "super" => module[..module.len().saturating_sub(1)].to_vec(),
                _ => Vec::new(),
            };
            starts.push((i, base, prefix.len()));
        }
    }
    // A relative path through a child module: `child::...` not after `::` or a word.
    for (i, _) in text.match_indices("::") {
        let name_start = text[..i]
            .rfind(|c: char| !is_word(c))
            .map_or(0, |at| at + 1);
        let name = &text[name_start..i];
        let before = &text[..name_start];
        if name.is_empty() || before.ends_with(':') || ["crate", "self", "super"].contains(&name) {
            continue;
        }
        let mut child = module.clone();
        child.push(name.to_string());
        if modules.contains_key(&child) {
            starts.push((name_start, module.clone(), 0));
        }
    }
    for (i, mut base, skip) in starts {
        let mut rest = &text[i + skip..];
        while let Some(after) = rest.strip_prefix("super::") {
            base.pop();
            rest = after;
        }
        for path in paths_after(rest) {
            let mut full = base.clone();
            full.extend(path);
            if let Some(target) = (1..=full.len())
                .rev()
                .map(|n| full[..n].to_vec())
                .find(|m| modules.contains_key(m))
            {
                found.push(target);
            }
        }
    }
    found
}

/// Violations in the library under `src` against `table`.
fn violations(src: &Path, table: &BTreeMap<String, BTreeSet<String>>) -> Vec<String> {
    let modules = library(src);
    let mut found = Vec::new();
    for (module, text) in &modules {
        let shown = module.join("::");
        let top = &module[0];
        for word in ["clap", "indicatif"] {
            if text.contains(&format!("{word}::")) {
                found.push(format!("{shown} names {word} (only the binary may)"));
            }
        }
        if text.contains("rapier3d") && *module != ["sim", "physics"] {
            found.push(format!("{shown} names rapier3d (only sim::physics may)"));
        }
        let Some(allowed) = table.get(top) else {
            found.push(format!(
                "{shown}: module {top} has no row in the layer table"
            ));
            continue;
        };
        let named: BTreeSet<String> = references(module, text, &modules)
            .into_iter()
            .map(|target| target[0].clone())
            .collect();
        for name in named {
            if name != *top && !allowed.contains(&name) {
                found.push(format!("{shown} imports {name}, which {top} may not"));
            }
        }
    }
    found
}

/// Circles in the module graph, as "a -> b -> a" lines (see the module overview).
fn cycles(src: &Path) -> Vec<String> {
    let modules = library(src);
    let mut edges: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for (module, text) in &modules {
        for target in references(module, without_tests(text), &modules) {
            let common = module
                .iter()
                .zip(&target)
                .take_while(|(a, b)| a == b)
                .count();
            if common == module.len() && common == target.len() {
                continue;
            }
            // Between a module and its ancestor, the edge runs from (or to) the ancestor itself
            // and the ancestor's child on the way to the other.
            let from = module[..module.len().min(common + 1)].to_vec();
            let to = target[..target.len().min(common + 1)].to_vec();
            edges.entry(from).or_default().insert(to);
        }
    }
    let mut found = BTreeSet::new();
    for start in edges.keys() {
        // Depth-first search for a path back to `start`.
        let mut stack = vec![(start.clone(), vec![start.clone()])];
        let mut seen = BTreeSet::new();
        while let Some((at, path)) = stack.pop() {
            for next in edges.get(&at).into_iter().flatten() {
                if next == start {
                    // Each circle once, from its smallest module.
                    let smallest = path.iter().min().expect("a path");
                    let from = path.iter().position(|m| m == smallest).expect("in path");
                    let turned: Vec<String> = path[from..]
                        .iter()
                        .chain(&path[..from])
                        .chain([smallest])
                        .map(|m| m.join("::"))
                        .collect();
                    found.insert(turned.join(" -> "));
                } else if seen.insert(next.clone()) {
                    let mut longer = path.clone();
                    longer.push(next.clone());
                    stack.push((next.clone(), longer));
                }
            }
        }
    }
    found.into_iter().collect()
}

/// A library tree in a temporary folder: (relative path, code) per file.
fn tree(name: &str, files: &[(&str, &str)]) -> PathBuf {
    let src = std::env::temp_dir().join(format!("surgvla-{name}-{}", std::process::id()));
    for (path, text) in files {
        let path = src.join(path);
        std::fs::create_dir_all(path.parent().expect("a parent")).expect("dir");
        std::fs::write(path, text).expect("write");
    }
    src
}

#[test]
fn the_module_graph_has_no_circle() {
    let found = cycles(&root().join("src"));
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn circles_are_found_between_files_and_across_folders() {
    let src = tree(
        "cycles",
        &[
            ("collect/mod.rs", "pub mod run;\npub mod report;\n"),
            ("collect/run.rs", "use crate::collect::report::Tally;\n"),
            ("collect/report.rs", "use super::run::SlotOutcome;\n"),
            ("collect/slot.rs", "use crate::collect::Thing;\n"),
            // The circle this layout once had: a format's checks and the dispatcher.
            ("export/mod.rs", "pub mod lerobot;\npub mod validate;\n"),
            (
                "export/validate.rs",
                "fn f() { crate::export::lerobot::check::check(); }\n",
            ),
            (
                "export/lerobot/mod.rs",
                "pub mod check;\nuse crate::export::Error;\n",
            ),
            (
                "export/lerobot/check/mod.rs",
                "pub mod rows;\nuse super::super::Error;\n",
            ),
            (
                "export/lerobot/check/rows.rs",
                "use crate::{episode::Step, export::validate::{At, Findings}};\n",
            ),
            // A folder's mod.rs that defines what its child imports and re-exports the child.
            (
                "policy/mod.rs",
                "pub mod plan;\npub use plan::Plan;\npub struct Waypoint;\n#[cfg(test)]\nmod tests {\n    use super::plan::Plan;\n}\n",
            ),
            (
                "policy/plan.rs",
                "use super::Waypoint;\npub struct Plan;\n#[cfg(test)]\nmod tests {\n    use super::*;\n}\n",
            ),
            // A façade whose children import each other, not it: no circle; nor is a test
            // module's `super::`.
            ("task/mod.rs", "mod id;\nmod spawn;\npub use id::TaskId;\n"),
            ("task/id.rs", "pub struct TaskId;\n"),
            (
                "task/spawn.rs",
                "use super::id::TaskId;\n#[cfg(test)]\nmod tests {\n    use super::super::TaskId;\n}\n",
            ),
            ("episode.rs", ""),
        ],
    );
    let found = cycles(&src);
    std::fs::remove_dir_all(&src).ok();
    assert!(
        found.contains(&"collect::report -> collect::run -> collect::report".to_string()),
        "{found:?}"
    );
    assert!(
        found.contains(&"export::lerobot -> export::validate -> export::lerobot".to_string()),
        "{found:?}"
    );
    assert!(
        found.contains(&"policy -> policy::plan -> policy".to_string()),
        "{found:?}"
    );
    assert_eq!(found.len(), 3, "{found:?}");
}

#[test]
fn the_library_keeps_its_layers() {
    let table = table();
    assert!(table.len() >= 14, "{table:?}");
    let found = violations(&root().join("src"), &table);
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn a_forbidden_import_is_found_however_it_is_written() {
    let src = tree(
        "layers",
        &[
            (
                "export/mod.rs",
                "//! crate::sim in a comment is fine\npub mod dir;\nuse crate::episode::Episode;\nuse super::sim::Simulator;\nfn f() { clap::Parser::parse(); }\n",
            ),
            (
                "export/dir.rs",
                "use crate as root;\nuse crate::{error::Kind, render::{Image}};\nfn f() { root::collect::run(); super::super::task::TaskId::ALL; }\n",
            ),
            ("episode.rs", ""),
            ("error.rs", ""),
            ("sim/mod.rs", ""),
            ("render/mod.rs", ""),
            ("collect/mod.rs", ""),
            ("task/mod.rs", ""),
        ],
    );
    let found = violations(&src, &table());
    std::fs::remove_dir_all(&src).ok();
    let named = |what: &str| found.iter().any(|f| f.contains(what));
    assert!(named("export imports sim"), "{found:?}");
    assert!(named("clap"), "{found:?}");
    assert!(named("export::dir imports render"), "{found:?}");
    assert!(named("export::dir imports collect"), "{found:?}");
    assert!(named("export::dir imports task"), "{found:?}");
    assert_eq!(found.len(), 5, "{found:?}");
}

/// The code map's paths: the first cell of each row, braces expanded
/// (`src/export/{rlds,zarr}/check.rs` is two paths).
fn code_map() -> Vec<String> {
    let text = std::fs::read_to_string(root().join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let section = text
        .split("## Code map")
        .nth(1)
        .expect("a Code map section");
    let mut paths = Vec::new();
    for line in section.lines().skip(2).take_while(|l| l.starts_with('|')) {
        let cell = line
            .trim_matches('|')
            .split('|')
            .next()
            .unwrap_or("")
            .trim();
        let path = cell.trim_matches('`');
        match (path.find('{'), path.find('}')) {
            (Some(open), Some(close)) => {
                for choice in path[open + 1..close].split(',') {
                    paths.push(format!("{}{choice}{}", &path[..open], &path[close + 1..]));
                }
            }
            _ => paths.push(path.to_string()),
        }
    }
    paths
}

#[test]
fn the_code_map_names_every_source_file_and_nothing_gone() {
    let paths = code_map();
    let mut files = Vec::new();
    rust_files(&root().join("src"), &mut files);
    let mut missing = Vec::new();
    for file in &files {
        let relative = file
            .strip_prefix(root())
            .expect("under the root")
            .to_string_lossy()
            .into_owned();
        // A file is named by its own row or by a folder row above it.
        let named = paths
            .iter()
            .any(|p| *p == relative || (p.ends_with('/') && relative.starts_with(p.as_str())));
        if !named {
            missing.push(relative);
        }
    }
    assert!(
        missing.is_empty(),
        "not in ARCHITECTURE.md's code map: {missing:?}"
    );
    let gone: Vec<&String> = paths
        .iter()
        .filter(|p| p.starts_with("src/") && !root().join(p.as_str()).exists())
        .collect();
    assert!(
        gone.is_empty(),
        "in the code map but not in the tree: {gone:?}"
    );
}
