//! The code's shape, checked: no module circles inside a crate, no source file longer
//! than a reader can hold, no function longer than one screen or two (with the list of
//! those that were, which may only shrink), and no test inside a binary whose test
//! harness is switched off.
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

/// Source files of a binary target: its root file and, for a `main.rs` or a root with a
/// folder of the same name beside it, the modules under that folder.
fn binary_sources(krate: &Path, path: &str) -> Vec<std::path::PathBuf> {
    let root = krate.join(path);
    let mut files = vec![root.clone()];
    let modules = if root.file_name().is_some_and(|n| n == "main.rs") {
        root.parent().map(Path::to_path_buf)
    } else {
        Some(root.with_extension(""))
    };
    if let Some(dir) = modules.filter(|d| d.is_dir()) {
        files.clear();
        rust_files(&dir, &mut files);
        if !files.contains(&root) {
            files.push(root);
        }
    }
    files
}

#[test]
fn no_binary_with_its_test_harness_off_holds_a_test() {
    // `test = false` on a `[[bin]]` saves CI a release compile and a link of a harness
    // with nothing in it; a test written there later would silently never run.
    let mut hidden = Vec::new();
    for krate in workspace_members() {
        let dir = workspace_root().join(&krate);
        let manifest: toml::Table = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap().parse().unwrap();
        let bins = manifest.get("bin").and_then(|b| b.as_array()).cloned().unwrap_or_default();
        for bin in bins {
            if bin.get("test").and_then(|t| t.as_bool()) != Some(false) {
                continue;
            }
            let path = bin["path"].as_str().expect("a [[bin]] with test = false names its path");
            for f in binary_sources(&dir, path) {
                let code = std::fs::read_to_string(&f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
                if code.contains("#[test]") || code.contains("proptest!") {
                    hidden.push(f.strip_prefix(workspace_root()).unwrap().display().to_string());
                }
            }
        }
    }
    assert!(
        hidden.is_empty(),
        "tests inside binaries whose Cargo.toml says `test = false` never run: remove that line, \
         or move the tests to the crate's library or tests/:\n{}",
        hidden.join("\n")
    );
}

/// Most lines of a function, from its signature to its closing brace.
const MAX_FUNCTION_LINES: usize = 80;

/// Convolution kernels may keep one kernel per function, however long.
const KERNEL_FOLDER: &str = "shared/nets/src/ops/conv/";

/// The functions over [`MAX_FUNCTION_LINES`] when this check came in, with their length
/// then: each may shrink, none may grow, and no function joins them. Split one along its
/// seams and delete its line.
const LONG_FUNCTIONS: &[(&str, &str, usize)] = &[
    ("deploy/pednav-bench/src/soak/report.rs", "build", 462),
    ("shared/sim/src/scene/mod.rs", "from_spec", 272),
    ("deploy/pednav-bench/src/soak/mod.rs", "run", 258),
    ("shared/sim/src/render/mod.rs", "new", 249),
    ("learner/src/dsac.rs", "update_here", 223),
    ("shared/bridge/src/learner_host.rs", "run_learner_host", 214),
    ("shared/runtime/src/memory.rs", "memory_estimate", 210),
    ("shared/runtime/src/config.rs", "validate", 175),
    ("shared/nets/src/ops/conv.rs", "backward", 172),
    ("shared/bridge/src/actor_host.rs", "run_actor_host", 146),
    ("shared/sim/src/render/mod.rs", "render_with", 141),
    ("shared/sim/src/traffic/vehicle.rs", "advance", 126),
    ("deploy/pednav-bench/src/bridge.rs", "run", 119),
    ("shared/experiments/src/bin/pednav-diagnose.rs", "main", 117),
    ("shared/experiments/src/bin/pednav-recognisability.rs", "main", 116),
    ("deploy/pednav-run/src/launch.rs", "launch", 115),
    ("shared/sim/src/oracle.rs", "plan", 108),
    ("deploy/pednav-run/src/supervisor.rs", "start", 108),
    ("deploy/pednav-run/src/supervisor.rs", "step", 97),
    ("shared/nets/src/ops/conv.rs", "forward", 92),
    ("shared/experiments/src/traffic_probe.rs", "collect", 91),
    ("shared/sim/src/traffic/walker.rs", "advance", 86),
    ("shared/sim/src/traffic/measure.rs", "measure", 86),
    ("shared/sim/src/draw.rs", "draw_map", 84),
    ("shared/sim/src/env.rs", "add_instances", 82),
    ("shared/experiments/src/plots.rs", "draw_chart", 82),
];

/// The name of the function a line declares, and the line's indentation.
fn function_signature(line: &str) -> Option<(usize, String)> {
    let indent = line.len() - line.trim_start().len();
    let mut rest = line.trim_start();
    let qualifiers = ["pub(crate) ", "pub(super) ", "pub ", "const ", "async ", "unsafe ", "extern \"C\" "];
    while let Some(q) = qualifiers.iter().find(|q| rest.starts_with(**q)) {
        rest = &rest[q.len()..];
    }
    let name: String =
        rest.strip_prefix("fn ")?.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
    (!name.is_empty()).then_some((indent, name))
}

/// `(name, lines)` of every function with a body in `code` before its `#[cfg(test)]`
/// module (rustfmt's layout: the closing brace at the signature's indentation).
fn function_lengths(code: &str) -> Vec<(String, usize)> {
    let lines: Vec<&str> = code.lines().take_while(|l| !l.starts_with("#[cfg(test)]")).collect();
    let mut found = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let Some((indent, name)) = function_signature(lines[i]) else {
            i += 1;
            continue;
        };
        // The signature ends at a line ending in `{` (a body follows), `;` (a
        // declaration) or `}` (a body on one line).
        let Some(end) = (i..lines.len()).find(|&j| lines[j].trim_end().ends_with(['{', ';', '}'])) else {
            break;
        };
        if lines[end].trim_end().ends_with('{') {
            let close = (end + 1..lines.len())
                .find(|&k| {
                    let l = lines[k];
                    l.len() - l.trim_start().len() == indent && l.trim_start().starts_with('}')
                })
                .unwrap_or(lines.len() - 1);
            found.push((name, close - i + 1));
        }
        i = end + 1;
    }
    found
}

#[test]
fn no_function_is_longer_than_two_screens_and_the_long_ones_only_shrink() {
    let mut over = Vec::new();
    let mut longest: BTreeMap<(String, String), usize> = BTreeMap::new();
    for krate in workspace_members() {
        let mut files = Vec::new();
        rust_files(&workspace_root().join(&krate).join("src"), &mut files);
        for f in files {
            let rel = f.strip_prefix(workspace_root()).unwrap().to_string_lossy().to_string();
            if rel.starts_with(KERNEL_FOLDER) {
                continue;
            }
            for (name, n) in function_lengths(&std::fs::read_to_string(&f).unwrap()) {
                let e = longest.entry((rel.clone(), name)).or_default();
                *e = (*e).max(n);
            }
        }
    }
    for ((file, name), n) in &longest {
        let allowed =
            LONG_FUNCTIONS.iter().find(|(f, m, _)| f == file && m == name).map_or(MAX_FUNCTION_LINES, |e| e.2);
        if *n > allowed {
            over.push(format!("{file}: fn {name} has {n} lines (at most {allowed})"));
        }
    }
    assert!(
        over.is_empty(),
        "functions over their limit: split them along their seams (one step, one helper):\n{}",
        over.join("\n")
    );
    let gone: Vec<_> = LONG_FUNCTIONS
        .iter()
        .filter(|(f, m, _)| longest.get(&(f.to_string(), m.to_string())).is_none_or(|&n| n <= MAX_FUNCTION_LINES))
        .collect();
    assert!(gone.is_empty(), "these are short now (or gone): delete their lines from LONG_FUNCTIONS: {gone:?}");
}

#[test]
fn the_function_check_measures_from_signature_to_closing_brace() {
    let code = "pub(crate) fn a(\n    x: u8,\n) -> u8 {\n    x\n}\nfn b() {}\nfn c();\nimpl S {\n    pub fn d() {\n        \
                let f = |y| y;\n    }\n}\n#[cfg(test)]\nfn e() {\n}\n";
    assert_eq!(function_lengths(code), vec![("a".to_string(), 5), ("d".to_string(), 3)]);
}
