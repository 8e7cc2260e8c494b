//! The layout is the architecture (#34): no two modules import each other, directly or round a
//! ring, at any level of the tree, and the pure core imports nothing from the edges. Read from
//! the source itself: every `crate::…`, `super::…` and `self::…` path in code (comments and test
//! modules aside) is an import.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The pure core: frame in, pose out, with no ROS, bag or command in sight.
const CORE: [&str; 6] = ["geometry", "consistency", "reject", "pnp", "verify", "pipeline"];
/// The edges: messages, bags, the node and the commands.
const EDGES: [&str; 7] = ["bag", "msgs", "node", "app", "play", "report", "tf_buffer"];

type Module = Vec<String>;

/// Every source file of `src/` but tests, with its module path.
fn modules() -> Vec<(Module, PathBuf)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    let mut stack = vec![root.clone()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("src/ is readable") {
            let path = entry.expect("a directory entry").path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_owned();
            if path.is_dir() {
                if name != "tests" {
                    stack.push(path);
                }
            } else if name.ends_with(".rs") && !name.ends_with("tests.rs") {
                let relative = path.strip_prefix(&root).expect("under src/").with_extension("");
                let mut module: Module =
                    relative.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
                if matches!(module.last().map(String::as_str), Some("mod" | "lib" | "main")) {
                    module.pop();
                }
                files.push((module, path));
            }
        }
    }
    files
}

/// The code of a file without its comments and `#[cfg(test)]` modules (which sit at the end).
fn code(path: &Path) -> String {
    let text = std::fs::read_to_string(path).expect("a readable source file");
    let text = match text.find("#[cfg(test)]\nmod ") {
        Some(at) => &text[..at],
        None => &text[..],
    };
    text.lines().map(|line| line.split("//").next().unwrap_or_default()).collect::<Vec<_>>().join("\n")
}

/// The module paths that `code` of `module` names.
fn imports(module: &Module, code: &str) -> Vec<Module> {
    let identifier = |c: char| c.is_alphanumeric() || c == '_';
    let mut found = Vec::new();
    for anchor in ["crate::", "super::", "self::"] {
        for (at, _) in code.match_indices(anchor) {
            if code[..at].chars().next_back().is_some_and(identifier) {
                continue;
            }
            let base: Module = match anchor {
                "crate::" => Vec::new(),
                "super::" => module[..module.len().saturating_sub(1)].to_vec(),
                _ => module.clone(),
            };
            let rest = &code[at + anchor.len()..];
            let groups: Vec<&str> = if let Some(inner) = rest.strip_prefix('{') {
                inner.split('}').next().unwrap_or_default().split(',').collect()
            } else {
                vec![rest]
            };
            for group in groups {
                let path: Module = group
                    .trim()
                    .split("::")
                    .map(|part| part.chars().take_while(|&c| identifier(c)).collect::<String>())
                    .take_while(|part| !part.is_empty())
                    .collect();
                found.push(base.iter().cloned().chain(path).collect());
            }
        }
    }
    found
}

/// Sibling edges: under each parent module, which child imports which.
fn sibling_edges() -> BTreeMap<Module, BTreeSet<(String, String)>> {
    let files = modules();
    let known: BTreeSet<Module> = files.iter().map(|(m, _)| m.clone()).collect();
    let mut edges: BTreeMap<Module, BTreeSet<(String, String)>> = BTreeMap::new();
    for (module, path) in &files {
        for target in imports(module, &code(path)) {
            let common = module.iter().zip(&target).take_while(|(a, b)| a == b).count();
            let (Some(from), Some(to)) = (module.get(common), target.get(common)) else { continue };
            if known.contains(&target[..=common]) {
                edges.entry(module[..common].to_vec()).or_default().insert((from.clone(), to.clone()));
            }
        }
    }
    edges
}

/// A ring of modules that import one another, if there is one.
fn ring(edges: &BTreeSet<(String, String)>) -> Option<Vec<String>> {
    let mut next: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (from, to) in edges {
        next.entry(from).or_default().push(to);
    }
    fn visit<'a>(
        node: &'a str,
        next: &BTreeMap<&'a str, Vec<&'a str>>,
        path: &mut Vec<&'a str>,
        done: &mut BTreeSet<&'a str>,
    ) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|&n| n == node) {
            return Some(path[at..].iter().chain([&node]).map(|n| n.to_string()).collect());
        }
        if !done.insert(node) {
            return None;
        }
        path.push(node);
        for &to in next.get(node).into_iter().flatten() {
            if let Some(ring) = visit(to, next, path, done) {
                return Some(ring);
            }
        }
        path.pop();
        None
    }
    let mut done = BTreeSet::new();
    next.keys().find_map(|&start| visit(start, &next, &mut Vec::new(), &mut done))
}

#[test]
fn no_two_modules_import_each_other_at_any_level() {
    let rings: Vec<String> = sibling_edges()
        .iter()
        .filter_map(|(parent, edges)| ring(edges).map(|r| format!("under `{}`: {}", parent.join("::"), r.join(" → "))))
        .collect();
    assert!(rings.is_empty(), "module import cycles:\n{}", rings.join("\n"));
}

#[test]
fn the_pure_core_imports_nothing_from_the_edges() {
    let edges = sibling_edges();
    let top = edges.get(&Vec::new()).cloned().unwrap_or_default();
    let leaks: Vec<String> = top
        .iter()
        .filter(|(from, to)| CORE.contains(&from.as_str()) && EDGES.contains(&to.as_str()))
        .map(|(from, to)| format!("{from} → {to}"))
        .collect();
    assert!(leaks.is_empty(), "the core imports the edges: {}", leaks.join(", "));
}

#[test]
fn the_import_reader_sees_the_imports_it_must() {
    // A check that could not fail would prove nothing: the reader finds pnp's scorer → coverage
    // import and the pipeline's import of pnp.
    let edges = sibling_edges();
    let pnp = edges.get(&vec!["pnp".to_owned()]).expect("pnp has sibling imports");
    assert!(pnp.contains(&("scorer".to_owned(), "coverage".to_owned())), "{pnp:?}");
    let top = edges.get(&Vec::new()).expect("the crate has sibling imports");
    assert!(top.contains(&("pipeline".to_owned(), "pnp".to_owned())), "{top:?}");
    let cyclic: BTreeSet<(String, String)> =
        [("a", "b"), ("b", "c"), ("c", "a")].iter().map(|(x, y)| (x.to_string(), y.to_string())).collect();
    assert_eq!(ring(&cyclic).map(|r| r.len()), Some(4));
}
