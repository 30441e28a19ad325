//! ARCHITECTURE.md's layer table, kept: every `crate::` path in a library module names only the
//! modules its row allows; the library never names clap or indicatif; only `src/sim/physics.rs`
//! names rapier; no two files of one folder import each other (directly or round a loop).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

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

/// Every `crate::name` a text names.
fn crate_paths(text: &str) -> BTreeSet<String> {
    text.match_indices("crate::")
        .filter(|(i, _)| !text[..*i].ends_with(|c: char| c.is_alphanumeric() || c == '_'))
        .map(|(i, _)| {
            text[i + 7..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect()
        })
        .collect()
}

/// Violations in the library under `src` against `table`.
fn violations(src: &Path, table: &BTreeMap<String, BTreeSet<String>>) -> Vec<String> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut found = Vec::new();
    for file in files {
        let relative = file.strip_prefix(src).expect("under src");
        let first = relative.components().next().expect("a component");
        let module = first
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        if module == "bin" || module == "lib" {
            continue;
        }
        let text = code(&file);
        let shown = relative.display();
        for word in ["clap", "indicatif"] {
            if text.contains(&format!("{word}::")) {
                found.push(format!("{shown} names {word} (only the binary may)"));
            }
        }
        if text.contains("rapier3d") && !relative.ends_with("sim/physics.rs") {
            found.push(format!("{shown} names rapier3d (only sim/physics.rs may)"));
        }
        let Some(allowed) = table.get(&module) else {
            found.push(format!(
                "{shown}: module {module} has no row in the layer table"
            ));
            continue;
        };
        for name in crate_paths(&text) {
            if name != module && !allowed.contains(&name) {
                found.push(format!(
                    "{shown} imports crate::{name}, which {module} may not"
                ));
            }
        }
    }
    found
}

/// The module path of a file under `src` ("collect::run"; a folder's mod.rs is the folder).
fn module_of(relative: &Path) -> Vec<String> {
    let mut parts: Vec<String> = relative
        .with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    parts
}

/// Cycles among sibling modules (files of one folder importing each other, directly or round a
/// loop), as "a -> b -> a" lines. A folder's mod.rs and its children are parent and child, not
/// siblings.
fn sibling_cycles(src: &Path) -> Vec<String> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let modules: BTreeMap<Vec<String>, String> = files
        .iter()
        .map(|f| {
            let relative = f.strip_prefix(src).expect("under src");
            (module_of(relative), code(f))
        })
        .filter(|(m, _)| m.first().is_some_and(|c| c != "bin" && c != "lib"))
        .collect();
    let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
    for (module, text) in &modules {
        let parent = &module[..module.len() - 1];
        let mut targets: Vec<Vec<String>> = Vec::new();
        for (prefix, base) in [("crate::", Vec::new()), ("super::", parent.to_vec())] {
            for (i, _) in text.match_indices(prefix) {
                if text[..i].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':') {
                    continue;
                }
                let path: String = text[i + prefix.len()..]
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                    .collect();
                let mut full = base.clone();
                full.extend(path.split("::").filter(|p| !p.is_empty()).map(String::from));
                targets.push(full);
            }
        }
        for target in targets {
            // The longest prefix that is a module of the library.
            let Some(found) = (1..=target.len())
                .rev()
                .map(|n| target[..n].to_vec())
                .find(|m| modules.contains_key(m))
            else {
                continue;
            };
            if found != *module
                && found.len() == module.len()
                && found[..found.len() - 1] == *parent
            {
                edges.entry(module.clone()).or_default().insert(found);
            }
        }
    }
    let mut cycles = Vec::new();
    for start in edges.keys() {
        // Depth-first search for a path back to `start`.
        let mut stack = vec![(start.clone(), vec![start.clone()])];
        let mut seen = BTreeSet::new();
        while let Some((at, path)) = stack.pop() {
            for next in edges.get(&at).into_iter().flatten() {
                if next == start {
                    let names: Vec<String> =
                        path.iter().chain([start]).map(|m| m.join("::")).collect();
                    cycles.push(names.join(" -> "));
                } else if seen.insert(next.clone()) {
                    let mut longer = path.clone();
                    longer.push(next.clone());
                    stack.push((next.clone(), longer));
                }
            }
        }
    }
    cycles
}

#[test]
fn no_sibling_modules_import_each_other() {
    let cycles = sibling_cycles(&root().join("src"));
    assert!(cycles.is_empty(), "{}", cycles.join("\n"));
}

#[test]
fn a_sibling_cycle_is_found() {
    let src = std::env::temp_dir().join(format!("surgvla-cycles-{}", std::process::id()));
    std::fs::create_dir_all(src.join("collect")).expect("dir");
    std::fs::write(
        src.join("collect/mod.rs"),
        "pub mod run;\npub mod report;\n",
    )
    .expect("mod");
    std::fs::write(
        src.join("collect/run.rs"),
        "use crate::collect::report::Tally;\n",
    )
    .expect("run");
    std::fs::write(
        src.join("collect/report.rs"),
        "use super::run::SlotOutcome;\n",
    )
    .expect("report");
    std::fs::write(src.join("collect/slot.rs"), "use crate::collect::Thing;\n").expect("slot");
    let cycles = sibling_cycles(&src);
    std::fs::remove_dir_all(&src).ok();
    assert!(
        cycles
            .iter()
            .any(|c| c == "collect::report -> collect::run -> collect::report"),
        "{cycles:?}"
    );
    assert!(cycles.iter().all(|c| !c.contains("slot")), "{cycles:?}");
}

#[test]
fn the_library_keeps_its_layers() {
    let table = table();
    assert!(table.len() >= 14, "{table:?}");
    let found = violations(&root().join("src"), &table);
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn a_forbidden_import_is_found() {
    let src = std::env::temp_dir().join(format!("surgvla-layers-{}", std::process::id()));
    std::fs::create_dir_all(src.join("export")).expect("dir");
    std::fs::write(
        src.join("export/mod.rs"),
        "//! crate::sim in a comment is fine\nuse crate::sim::Simulator;\nuse crate::episode::Episode;\nfn f() { clap::Parser::parse(); }\n",
    )
    .expect("write");
    let found = violations(&src, &table());
    std::fs::remove_dir_all(&src).ok();
    assert_eq!(found.len(), 2, "{found:?}");
    assert!(found.iter().any(|f| f.contains("crate::sim")), "{found:?}");
    assert!(found.iter().any(|f| f.contains("clap")), "{found:?}");
}
