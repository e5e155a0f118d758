//! The codebase's shape, checked: no import loops between the modules of a crate, module docs
//! that fit a screen, no history in the sources, a README that stays a front door and points
//! nowhere outside the repository.
//!
//! The module graph: each source file is a node; a file has an edge to every other file whose
//! module an item path in it names (`crate::a::b::Item`, `super::x`, `self::y`, also inside
//! `use …::{…}` groups), outside its `#[cfg(test)] mod tests`. A parent's edges to its own
//! children are left out (a `mod.rs` re-exporting or dispatching to its submodules is the
//! folder's interface, not a loop); a child naming its parent's items stays an edge.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use test_support::repo_root;

/// Every `.rs` file under `dir` with its text, by path relative to `dir`.
fn rust_files(dir: &Path) -> BTreeMap<PathBuf, String> {
    test_support::file_map(dir)
        .into_iter()
        .filter(|(p, _)| p.ends_with(".rs"))
        .map(|(p, bytes)| (dir.join(p), String::from_utf8_lossy(&bytes).into_owned()))
        .collect()
}

/// The module path of a source file relative to its crate's `src` folder.
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap_or(file).with_extension("");
    let mut parts: Vec<String> = rel.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
    if parts.last().is_some_and(|l| l == "lib" || l == "main" || l == "mod") {
        parts.pop();
    }
    parts
}

/// The text of a file outside its unit-test module and without line comments.
fn code_of(text: &str) -> String {
    let head = text.split("#[cfg(test)]\nmod tests").next().unwrap_or(text);
    head.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n")
}

fn is_ident_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Item paths named in `code` that start at `crate`, `super` or `self`, as segment lists (the
/// first segment is the anchor). A `use` group `a::{b, c::d}` yields `a::b` and `a::c`.
fn item_paths(code: &str) -> Vec<Vec<String>> {
    let chars: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let at_word = i == 0 || !is_ident_char(chars[i - 1]) && chars[i - 1] != ':';
        let rest: String = chars[i..chars.len().min(i + 5)].iter().collect();
        let anchor = ["crate", "super", "self"].into_iter().find(|a| rest.starts_with(a));
        let Some(anchor) = anchor.filter(|a| at_word && chars.get(i + a.len()) == Some(&':')) else {
            i += 1;
            continue;
        };
        let mut segs = vec![anchor.to_string()];
        let mut j = i + anchor.len();
        loop {
            if chars.get(j) == Some(&':') && chars.get(j + 1) == Some(&':') {
                j += 2;
            } else {
                break;
            }
            if chars.get(j) == Some(&'{') {
                // a group: each member's first segment
                let close = chars[j..].iter().position(|&c| c == '}').map_or(chars.len(), |p| j + p);
                let inner: String = chars[j + 1..close].iter().collect();
                for member in inner.split(',') {
                    let member = member.split('{').next().unwrap_or("");
                    let mut p = segs.clone();
                    for word in member.trim().split("::") {
                        let word: String = word.trim().chars().take_while(|&c| is_ident_char(c)).collect();
                        if word.is_empty() || word == "self" {
                            break;
                        }
                        p.push(word);
                    }
                    if p.len() > segs.len() {
                        out.push(p);
                    }
                }
                segs.clear();
                j = close;
                break;
            }
            let word: String = chars[j..].iter().take_while(|&&c| is_ident_char(c)).collect();
            if word.is_empty() {
                break;
            }
            j += word.len();
            segs.push(word);
        }
        if segs.len() > 1 {
            out.push(segs);
        }
        i = j.max(i + 1);
    }
    out
}

/// The import edges between a crate's files (see the module doc).
fn module_graph(src: &Path) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
    let modules: BTreeMap<Vec<String>, String> =
        rust_files(src).into_iter().map(|(f, text)| (module_path(src, &f), text)).collect();
    let mut edges: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
    for (m, text) in &modules {
        let mut to = BTreeSet::new();
        for path in item_paths(&code_of(text)) {
            let mut cur: Vec<String> = match path[0].as_str() {
                "crate" => Vec::new(),
                "self" => m.clone(),
                _ => m[..m.len().saturating_sub(1)].to_vec(),
            };
            let mut segs = &path[1..];
            while segs.first().is_some_and(|s| s == "super") {
                cur.pop();
                segs = &segs[1..];
            }
            let mut target = None;
            for s in segs {
                cur.push(s.clone());
                if modules.contains_key(&cur) {
                    target = Some(cur.clone());
                } else {
                    break;
                }
            }
            if let Some(t) = target {
                let parent_to_child = t.len() > m.len() && t[..m.len()] == m[..];
                if &t != m && !parent_to_child {
                    to.insert(t);
                }
            }
        }
        edges.insert(m.clone(), to);
    }
    edges
}

/// The strongly connected components with more than one node (Tarjan).
fn cycles(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<Vec<Vec<String>>> {
    struct State<'a> {
        edges: &'a BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        index: BTreeMap<Vec<String>, usize>,
        low: BTreeMap<Vec<String>, usize>,
        stack: Vec<Vec<String>>,
        out: Vec<Vec<Vec<String>>>,
    }
    fn visit(s: &mut State, v: &Vec<String>) {
        let n = s.index.len();
        s.index.insert(v.clone(), n);
        s.low.insert(v.clone(), n);
        s.stack.push(v.clone());
        for w in s.edges.get(v).into_iter().flatten() {
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = s.stack.pop() {
                let done = &w == v;
                comp.push(w);
                if done {
                    break;
                }
            }
            if comp.len() > 1 {
                s.out.push(comp);
            }
        }
    }
    let mut s = State { edges, index: BTreeMap::new(), low: BTreeMap::new(), stack: Vec::new(), out: Vec::new() };
    for v in edges.keys() {
        if !s.index.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}

/// Every crate's `src` folder, and xtask's.
fn source_roots() -> Vec<PathBuf> {
    let root = repo_root();
    let mut roots: Vec<PathBuf> = std::fs::read_dir(root.join("crates"))
        .unwrap()
        .flatten()
        .map(|e| e.path().join("src"))
        .filter(|p| p.is_dir())
        .collect();
    roots.push(root.join("xtask/src"));
    roots.sort();
    roots
}

#[test]
fn the_checker_finds_a_loop_and_passes_a_tree() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path();
    std::fs::create_dir_all(src.join("models")).unwrap();
    std::fs::write(src.join("lib.rs"), "pub mod a;\npub mod b;\npub mod models;\n").unwrap();
    std::fs::write(src.join("a.rs"), "use crate::b::Thing;\n").unwrap();
    std::fs::write(src.join("b.rs"), "use crate::{models::fast::Cfg, x};\n").unwrap();
    std::fs::write(src.join("models/mod.rs"), "pub mod fast;\npub use fast::Cfg;\n").unwrap();
    std::fs::write(src.join("models/fast.rs"), "use super::super::a::f;\n// use crate::b::g;\n").unwrap();
    let found = cycles(&module_graph(src));
    assert_eq!(found.len(), 1, "{found:?}");
    let mut names: Vec<String> = found[0].iter().map(|m| m.join("::")).collect();
    names.sort();
    assert_eq!(names, ["a", "b", "models::fast"]);
    // the loop broken: the fast model no longer names `a`
    std::fs::write(src.join("models/fast.rs"), "use super::Other;\n").unwrap();
    assert!(cycles(&module_graph(src)).is_empty());
}

#[test]
fn no_import_loops_between_modules() {
    let mut found = Vec::new();
    for src in source_roots() {
        for comp in cycles(&module_graph(&src)) {
            let names: Vec<String> = comp.iter().map(|m| m.join("::")).collect();
            found.push(format!("{}: {}", src.display(), names.join(" <-> ")));
        }
    }
    assert!(found.is_empty(), "import loops:\n{}", found.join("\n"));
}

/// The leading `//!` block of a file.
fn module_doc_lines(text: &str) -> usize {
    text.lines().skip_while(|l| l.trim().is_empty()).take_while(|l| l.trim_start().starts_with("//!")).count()
}

#[test]
fn module_docs_fit_a_screen_and_carry_no_history() {
    let history = |l: &str| {
        let lower = l.to_ascii_lowercase();
        ["stop ", "session "].iter().any(|w| {
            lower.match_indices(w).any(|(i, _)| {
                let before_ok = i == 0 || !lower.as_bytes()[i - 1].is_ascii_alphabetic();
                before_ok && lower[i + w.len()..].starts_with(|c: char| c.is_ascii_digit())
            })
        })
    };
    let mut long = Vec::new();
    let mut dated = Vec::new();
    let root = repo_root();
    let mut files: BTreeMap<PathBuf, String> = source_roots().iter().flat_map(|s| rust_files(s)).collect();
    for extra in ["crates/pathtracer/tests", "crates/pathtracer/benches", "crates/nerf/tests", "tests/tests", "xtask/tests"] {
        files.extend(rust_files(&root.join(extra)));
    }
    for (f, text) in files {
        let n = module_doc_lines(&text);
        if n > 45 {
            long.push(format!("{} ({n} lines)", f.display()));
        }
        for (k, l) in text.lines().enumerate() {
            if history(l) || ["DESIGN.md", "STYLE.md"].iter().any(|f| l.contains(&format!("shared/{f}"))) {
                dated.push(format!("{}:{}: {}", f.display(), k + 1, l.trim()));
            }
        }
    }
    assert!(
        long.is_empty() && dated.is_empty(),
        "module docs over ~40 lines (move the rest to docs/):\n{}\nhistory in the sources (it belongs in git log and docs/experiments.md):\n{}",
        long.join("\n"),
        dated.join("\n")
    );
}

#[test]
fn readme_is_a_front_door_and_docs_stay_inside_the_repository() {
    let root = repo_root();
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    assert!(readme.lines().count() <= 150, "README.md has {} lines (at most 150)", readme.lines().count());
    let mut docs: Vec<(PathBuf, String)> = vec![(root.join("README.md"), readme.clone())];
    for (rel, bytes) in test_support::file_map(&root.join("docs")) {
        if rel.ends_with(".md") {
            docs.push((root.join("docs").join(rel), String::from_utf8_lossy(&bytes).into_owned()));
        }
    }
    assert!(docs.iter().any(|(p, _)| p.ends_with("docs/design.md")), "docs/design.md is missing");
    for (doc, text) in docs {
        // every relative link target resolves inside the repository and exists
        for (k, line) in text.lines().enumerate() {
            let mut rest = line;
            while let Some(p) = rest.find("](") {
                let after = &rest[p + 2..];
                let end = after.find(')').unwrap_or(after.len());
                let target = after[..end].split('#').next().unwrap_or("");
                rest = &after[end.min(after.len())..];
                if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                let resolved = doc.parent().unwrap().join(target);
                let inside = resolved.canonicalize().map(|c| c.starts_with(root.canonicalize().unwrap()));
                assert!(
                    matches!(inside, Ok(true)),
                    "{}:{}: link '{target}' does not name a file inside the repository",
                    doc.display(),
                    k + 1
                );
            }
            assert!(!line.contains("../shared"), "{}:{}: names a path outside the repository", doc.display(), k + 1);
        }
    }
}
