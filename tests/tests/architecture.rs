//! The code's shape, checked: no module circles inside a crate, and no source file
//! longer than a reader can hold.
//!
//! Within each library crate, module A depends on module B when A's code (outside
//! comments and its `#[cfg(test)]` part) names `crate::B`; a module's submodules count
//! as the module. A circle (A → B → … → A) means neither can be read, tested or moved
//! without the other: one of them owns something that belongs to the other, or to a
//! third module below both. Binaries (`src/bin/`, `main.rs`) are wiring, not checked.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use pednav_tests::workspace_root;

/// The workspace's members (`Cargo.toml`'s `workspace.members`), so a new crate is
/// checked without anyone remembering to list it here.
fn workspace_members() -> Vec<String> {
    let path = workspace_root().join("Cargo.toml");
    let manifest: toml::Table = std::fs::read_to_string(&path).unwrap().parse().unwrap();
    let members = manifest["workspace"]["members"].as_array().expect("workspace.members is a list");
    members.iter().map(|m| m.as_str().expect("a member is a path").to_string()).collect()
}

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = entry.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// `crate::X` names in `code` (comments and the `#[cfg(test)]` part cut off); a group
/// `crate::{a, b::c}` names `a` and `b`.
fn crate_references(code: &str) -> BTreeSet<String> {
    let code = code.split("#[cfg(test)]").next().unwrap_or_default();
    let code: String = code.lines().map(|l| l.split("//").next().unwrap_or_default()).collect::<Vec<_>>().join("\n");
    let ident = |s: &str| -> String { s.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect() };
    let mut refs = BTreeSet::new();
    let mut rest = code.as_str();
    while let Some(i) = rest.find("crate::") {
        rest = &rest[i + 7..];
        if let Some(group) = rest.strip_prefix('{') {
            // Top-level items of the group: split on commas outside nested braces.
            let (mut depth, mut start) = (0usize, 0usize);
            for (j, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => {
                        refs.insert(ident(group[start..j].trim()));
                        break;
                    }
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        refs.insert(ident(group[start..j].trim()));
                        start = j + 1;
                    }
                    _ => {}
                }
            }
        } else {
            refs.insert(ident(rest));
        }
    }
    refs.remove("");
    refs
}

/// The module graph of one crate: top-level module → the modules it names.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in files {
        let rel = f.strip_prefix(src).unwrap().to_string_lossy().to_string();
        if rel.starts_with("bin/") || rel == "lib.rs" || rel == "main.rs" {
            continue;
        }
        let top = rel.split('/').next().unwrap().trim_end_matches(".rs").to_string();
        let refs = crate_references(&std::fs::read_to_string(&f).unwrap());
        graph.entry(top.clone()).or_default().extend(refs.into_iter().filter(|r| *r != top));
    }
    graph
}

/// One circle of `graph`, if it has any.
fn find_circle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == n) {
            let mut circle = path[i..].to_vec();
            circle.push(n.to_string());
            return Some(circle);
        }
        if done.contains(n) {
            return None;
        }
        path.push(n.to_string());
        for m in graph.get(n).into_iter().flatten().filter(|m| graph.contains_key(*m)) {
            if let Some(c) = visit(m, graph, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(n.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph.keys().find_map(|n| visit(n, graph, &mut Vec::new(), &mut done))
}

#[test]
fn no_crate_has_a_module_circle() {
    let mut circles = Vec::new();
    let members = workspace_members();
    assert!(members.len() >= 10, "workspace members: {members:?}");
    for krate in &members {
        let src = workspace_root().join(krate).join("src");
        if let Some(c) = find_circle(&module_graph(&src)) {
            circles.push(format!("{krate}: {}", c.join(" → ")));
        }
    }
    assert!(circles.is_empty(), "module circles:\n{}", circles.join("\n"));
}

#[test]
fn the_check_finds_a_circle_when_there_is_one() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("dsac", vec!["replay", "checkpoint"]),
        ("checkpoint", vec!["dsac"]),
        ("replay", vec!["error"]),
        ("error", vec![]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(find_circle(&graph), Some(vec!["checkpoint".into(), "dsac".into(), "checkpoint".into()]));
    let refs =
        crate_references("use crate::dsac::Dsac; // crate::ignored\n/// [`crate::doc`]\nfn f() { crate::error::x() }");
    assert_eq!(refs, ["dsac", "error"].into_iter().map(String::from).collect());
    let grouped =
        crate_references("use crate::{\n    replay::{DualReplay, Batch},\n    nets, // crate::no\n    Error,\n};");
    assert_eq!(grouped, ["replay", "nets", "Error"].into_iter().map(String::from).collect());
}

/// Most lines of a source file, not counting its `#[cfg(test)]` module.
const MAX_LINES: usize = 600;

/// Lines of `code` before its `#[cfg(test)]` module (at the start of a line).
fn lines_before_tests(code: &str) -> usize {
    code.lines().take_while(|l| !l.starts_with("#[cfg(test)]")).count()
}

/// Whether the module doc (the leading `//!` lines) says the file is one algorithm or
/// kernel family that reads top to bottom: the one reason to be longer.
fn reads_top_to_bottom(code: &str) -> bool {
    let doc: String = code.lines().take_while(|l| l.starts_with("//!")).collect::<Vec<_>>().join(" ");
    doc.split_whitespace().collect::<Vec<_>>().join(" ").contains("reads top to bottom")
}

#[test]
fn no_source_file_is_longer_than_a_reader_can_hold() {
    let mut long = Vec::new();
    for krate in workspace_members() {
        let mut files = Vec::new();
        for dir in ["src", "tests", "benches"] {
            rust_files(&workspace_root().join(&krate).join(dir), &mut files);
        }
        for f in files {
            let code = std::fs::read_to_string(&f).unwrap();
            let n = lines_before_tests(&code);
            if n > MAX_LINES && !reads_top_to_bottom(&code) {
                long.push(format!("{} ({n} lines)", f.strip_prefix(workspace_root()).unwrap().display()));
            }
        }
    }
    assert!(
        long.is_empty(),
        "files over {MAX_LINES} lines (tests not counted): split them along their seams, or say in the module doc \
         that the file is one algorithm that reads top to bottom:\n{}",
        long.join("\n")
    );
}

#[test]
fn the_length_check_counts_code_before_the_tests_and_reads_the_module_doc() {
    let code = "//! Kernels: one family that\n//! reads top to bottom.\nfn a() {}\n#[cfg(test)]\nmod tests {}\n";
    assert_eq!(lines_before_tests(code), 3);
    assert!(reads_top_to_bottom(code));
    assert!(!reads_top_to_bottom("//! Kernels.\nfn a() {} // reads top to bottom\n"));
}
