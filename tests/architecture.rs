//! The crate's layers (docs/architecture.md), checked on the source text:
//! every `crate::…` and `super::…` path in `src/**/*.rs` (`use` lines and paths
//! written inline, comments excluded) is resolved to the file of the module it
//! names. Two rules:
//!
//! 1. a top-level module uses only the modules `ALLOWED` lists for it;
//! 2. the graph of files (an edge where one file names a module of another)
//!    has no cycle.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Per top-level module: the top-level modules it may use. A module missing
/// here fails the test: a new module needs its place in the layers.
const ALLOWED: &[(&str, &[&str])] = &[
    ("config", &[]),
    ("rng", &[]),
    ("spectrum", &[]),
    ("microfacet", &["config", "rng", "spectrum"]),
    ("walk", &["microfacet", "config", "rng", "spectrum"]),
    ("tables", &["microfacet", "config", "rng", "spectrum"]),
    ("microgeometry", &["microfacet", "config", "rng", "spectrum"]),
    ("models", &["tables", "walk", "microfacet", "config", "rng", "spectrum"]),
    ("bsdf", &["models", "tables", "walk", "microfacet", "config", "rng", "spectrum"]),
    ("ffi", &["bsdf", "microgeometry", "models", "tables", "walk", "microfacet", "config", "rng", "spectrum"]),
];

struct Source {
    /// Module path: `src/models/heitz/mod.rs` → ["models", "heitz"].
    module: Vec<String>,
    /// The text with comments removed.
    code: String,
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The text without `//` and `/* */` comments (string literals are kept, so a
/// `//` inside a string would cut the line: the crate has none that matters).
fn strip_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix("/*") {
            rest = after.find("*/").map_or("", |i| &after[i + 2..]);
        } else if rest.starts_with("//") {
            rest = rest.find('\n').map_or("", |i| &rest[i..]);
        } else {
            let c = rest.chars().next().unwrap();
            out.push(c);
            rest = &rest[c.len_utf8()..];
        }
    }
    out
}

fn sources() -> BTreeMap<PathBuf, Source> {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files
        .into_iter()
        .map(|path| {
            let rel = path.strip_prefix(&src).unwrap().with_extension("");
            let mut module: Vec<String> = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
            if matches!(module.last().map(String::as_str), Some("mod" | "lib")) {
                module.pop();
            }
            let code = strip_comments(&std::fs::read_to_string(&path).unwrap());
            (path, Source { module, code })
        })
        .collect()
}

fn ident_len(s: &str) -> usize {
    s.find(|c: char| !(c.is_alphanumeric() || c == '_')).unwrap_or(s.len())
}

/// Expands the use tree at the start of `s` (after `crate::` or `super::`)
/// into its paths: `a::{b, c::d}` → [a, b], [a, c, d].
fn use_tree(s: &str, prefix: &[String], out: &mut Vec<Vec<String>>) -> usize {
    let s_trim = s.trim_start();
    let mut pos = s.len() - s_trim.len();
    if let Some(inner) = s_trim.strip_prefix('{') {
        pos += 1;
        let mut at = 0;
        loop {
            let rest = &inner[at..];
            let rest_trim = rest.trim_start();
            at += rest.len() - rest_trim.len();
            if rest_trim.starts_with('}') {
                return pos + at + 1;
            }
            if rest_trim.starts_with(',') {
                at += 1;
                continue;
            }
            let used = use_tree(&inner[at..], prefix, out);
            if used == 0 {
                return pos + at;
            }
            at += used;
        }
    }
    let n = ident_len(s_trim);
    if n == 0 {
        out.push(prefix.to_vec());
        return if s_trim.starts_with('*') { pos + 1 } else { pos };
    }
    let mut path = prefix.to_vec();
    path.push(s_trim[..n].to_string());
    pos += n;
    if let Some(after) = s[pos..].strip_prefix("::") {
        return pos + 2 + use_tree(after, &path, out);
    }
    out.push(path);
    // `a as b`: the alias names nothing new.
    let rest = &s[pos..];
    let rest_trim = rest.trim_start();
    if let Some(alias) = rest_trim.strip_prefix("as ") {
        let alias_trim = alias.trim_start();
        return pos + (rest.len() - alias_trim.len()) + ident_len(alias_trim);
    }
    pos
}

/// Every module path the code names through `crate::` or `super::`, as full
/// paths from the crate root (items included: resolved to modules later).
fn named_paths(src: &Source) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let code = &src.code;
    let mut i = 0;
    while let Some(off) = code[i..].find("crate::") {
        let at = i + off;
        let before = code[..at].chars().next_back();
        i = at + "crate::".len();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '$') {
            continue;
        }
        use_tree(&code[i..], &[], &mut out);
    }
    // `super::` relative to the file's module, outside the inline test module
    // (whose `super` is the file itself).
    let body = code.split("#[cfg(test)]").next().unwrap();
    let mut i = 0;
    while let Some(off) = body[i..].find("super::") {
        let at = i + off;
        let before = body[..at].chars().next_back();
        i = at + "super::".len();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
            continue;
        }
        let mut base = src.module.clone();
        base.pop();
        let mut rest = &body[i..];
        while let Some(r) = rest.strip_prefix("super::") {
            base.pop();
            rest = r;
            i += "super::".len();
        }
        use_tree(rest, &base, &mut out);
    }
    out.retain(|p| !p.is_empty());
    out
}

/// The file of the longest module prefix of `path`.
fn resolve<'a>(path: &[String], modules: &'a BTreeMap<Vec<String>, PathBuf>) -> Option<&'a PathBuf> {
    (1..=path.len()).rev().find_map(|n| modules.get(&path[..n]))
}

#[test]
fn top_level_modules_use_only_the_layers_below() {
    let sources = sources();
    let allowed: BTreeMap<&str, &[&str]> = ALLOWED.iter().copied().collect();
    let mut violations = Vec::new();
    for (path, src) in &sources {
        let Some(top) = src.module.first() else { continue }; // lib.rs
        let Some(may) = allowed.get(top.as_str()) else {
            violations.push(format!("{}: module `{top}` has no entry in ALLOWED (docs/architecture.md)", path.display()));
            continue;
        };
        let used: BTreeSet<String> = named_paths(src).into_iter().map(|p| p[0].clone()).collect();
        for u in used {
            if u != *top && !may.contains(&u.as_str()) {
                violations.push(format!("{}: `{top}` uses `crate::{u}`", path.display()));
            }
        }
    }
    assert!(violations.is_empty(), "layer violations (docs/architecture.md):\n{}", violations.join("\n"));
}

#[test]
fn no_cycle_between_files() {
    let sources = sources();
    let modules: BTreeMap<Vec<String>, PathBuf> = sources.iter().map(|(p, s)| (s.module.clone(), p.clone())).collect();
    let mut edges: BTreeMap<&PathBuf, BTreeSet<&PathBuf>> = BTreeMap::new();
    for (path, src) in &sources {
        let targets = edges.entry(path).or_default();
        for named in named_paths(src) {
            if let Some(target) = resolve(&named, &modules) {
                if target != path {
                    targets.insert(target);
                }
            }
        }
    }
    // Depth-first search; a grey file met again closes a cycle.
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        Grey,
        Black,
    }
    fn visit<'a>(
        f: &'a PathBuf,
        edges: &BTreeMap<&'a PathBuf, BTreeSet<&'a PathBuf>>,
        marks: &mut BTreeMap<&'a PathBuf, Mark>,
        stack: &mut Vec<&'a PathBuf>,
    ) -> Option<Vec<&'a PathBuf>> {
        match marks.get(f) {
            Some(Mark::Black) => return None,
            Some(Mark::Grey) => {
                let start = stack.iter().position(|g| *g == f).unwrap();
                return Some(stack[start..].to_vec());
            }
            None => {}
        }
        marks.insert(f, Mark::Grey);
        stack.push(f);
        for &t in edges.get(f).into_iter().flatten() {
            if let Some(cycle) = visit(t, edges, marks, stack) {
                return Some(cycle);
            }
        }
        stack.pop();
        marks.insert(f, Mark::Black);
        None
    }
    let mut marks = BTreeMap::new();
    for &f in edges.keys() {
        if let Some(cycle) = visit(f, &edges, &mut marks, &mut Vec::new()) {
            let names: Vec<_> = cycle.iter().map(|p| p.display().to_string()).collect();
            panic!("the files form a cycle: {} → (back to the first)", names.join(" → "));
        }
    }
}

/// The scanner itself: use trees, `super`, comments.
#[test]
fn scanner_reads_paths() {
    let src = Source {
        module: vec!["models".into(), "heitz".into()],
        code: strip_comments(
            "use crate::config::{Estimator, Surface};\n// use crate::bsdf::Bsdf;\nuse super::{mis, posfree::{Segments, dielectric as d}};\nlet x = crate::tables::albedo::AlbedoTable::get(d);\n/* crate::ffi */",
        ),
    };
    let paths: Vec<String> = named_paths(&src).iter().map(|p| p.join("::")).collect();
    assert_eq!(
        paths,
        [
            "config::Estimator",
            "config::Surface",
            "tables::albedo::AlbedoTable::get",
            "models::mis",
            "models::posfree::Segments",
            "models::posfree::dielectric"
        ]
    );
}
