//! No import circles between the modules of a crate: a module that uses another may not be
//! used by it, directly or around a longer loop. A circle means two modules are one piece
//! of code in two files; it is broken by moving the shared piece where it belongs.
//!
//! The check reads every `src/` file of every crate in the repository (the workspace members,
//! the freestanding crates and the fuzz crate), finds each file's module from its place under
//! `src/`, and follows the paths the file's code names: `use` trees and paths in the code that
//! start with `crate::`, `super::`, `self::` or a child module's name, with inline modules
//! (`mod tests { use super::*; }`) resolved as the compiler does. A path leads to the file of
//! the longest module prefix it names. Comments, doc comments and string literals are skipped.
//! Then every strongly connected set of two or more files is a circle.
//!
//! The crate root (`lib.rs`, or `main.rs` without one) is left out: it declares the modules
//! and re-exports their items, so it names every module and many modules name it
//! (`crate::Environment`); that is the crate's index, not a circle between two pieces of code.
//! What the root defines itself should be what every module shares, and nothing more.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Circles that existed when this check was written, as pairs of modules of one crate
/// (`crate, a, b`): the edges between `a` and `b` are left out of the search. Each is to be
/// broken by moving the shared piece where it belongs, and then removed here; an entry whose
/// modules no longer share a circle fails the test, so this list only shrinks.
const KNOWN_CIRCLES: &[(&str, &str, &str)] = &[];

#[test]
fn no_module_imports_one_that_imports_it_back() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut problems = Vec::new();
    let mut crates_seen = 0;
    for dir in crate_dirs(root) {
        let name = crate_name(&dir);
        let files = source_files(&dir.join("src"));
        let graph = module_graph(&files);
        crates_seen += 1;
        let known: Vec<(&str, &str)> = KNOWN_CIRCLES
            .iter()
            .filter(|(c, _, _)| *c == name)
            .map(|(_, a, b)| (*a, *b))
            .collect();
        for &(a, b) in &known {
            let whole = circles(&graph, &[]);
            if !whole.iter().any(|c| c.contains(a) && c.contains(b)) {
                problems.push(format!(
                    "{name}: `{a}` and `{b}` no longer share a circle: remove them from KNOWN_CIRCLES"
                ));
            }
        }
        for circle in circles(&graph, &known) {
            problems.push(format!("{name}: {}", describe(&graph, &circle)));
        }
    }
    assert!(
        crates_seen >= 6,
        "found only {crates_seen} crates under {root:?}"
    );
    assert!(
        problems.is_empty(),
        "import circles:\n{}",
        problems.join("\n")
    );
}

/// The check finds what it is meant to find, on made-up files: a two-file circle through
/// `use crate::`, a child using its parent through `super::` while the parent names the child,
/// and a three-file loop of inline paths; not the paths in comments, strings, visibility
/// restrictions or an inline test module's `use super::*`, nor those to or from the crate root.
#[test]
fn the_check_finds_circles_and_only_circles() {
    let files = [
        (
            "lib.rs",
            "mod a; mod b; mod c; mod p; mod x; mod y; mod z; pub use c::g; const K: u8 = x::K;",
        ),
        ("a.rs", "use crate::b::Thing; // crate::c::Other\n"),
        (
            "b.rs",
            "use crate::{a::{self, A}, c};\nfn f() { let s = \"crate::c::X\"; }",
        ),
        (
            "c.rs",
            "pub(in crate::x) fn g() {}\n/* crate::a::A /* nested */ crate::b */\n\
             mod tests { use super::*; use crate::c::g; }",
        ),
        ("p/mod.rs", "mod q;\nfn f() { q::run() }"),
        ("p/q.rs", "use super::Shared; fn run() {}"),
        (
            "x.rs",
            "fn f() { crate::y::f(); let c = 'a'; let l: &'static str = \"\"; }",
        ),
        ("y.rs", "fn f() -> crate::z::T { crate::Root::new() }"),
        (
            "z.rs",
            "type T = u8; fn h() { r#\"crate::c\"#; super::x::f() }",
        ),
    ];
    let files: Vec<(PathBuf, String)> = files
        .iter()
        .map(|(p, s)| (PathBuf::from(p), s.to_string()))
        .collect();
    let graph = module_graph(&files);
    let found: BTreeSet<Vec<String>> = circles(&graph, &[])
        .into_iter()
        .map(|c| c.into_iter().collect())
        .collect();
    let expect: BTreeSet<Vec<String>> = [vec!["a", "b"], vec!["p", "p::q"], vec!["x", "y", "z"]]
        .into_iter()
        .map(|c| c.into_iter().map(String::from).collect())
        .collect();
    assert_eq!(found, expect, "{graph:#?}");
    // c is used by b, and uses nobody: no edge from its comment, visibility or test module.
    assert!(graph["c"].is_empty(), "{:?}", graph["c"]);
    // A known pair is left out of the search.
    assert_eq!(circles(&graph, &[("a", "b")]).len(), 2);
}

/// Directories holding a crate: a `Cargo.toml` with a `[package]` and a `src/` beside it.
fn crate_dirs(root: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let manifest = dir.join("Cargo.toml");
        if manifest.is_file()
            && dir.join("src").is_dir()
            && std::fs::read_to_string(&manifest).is_ok_and(|s| s.contains("[package]"))
        {
            out.push(dir.clone());
        }
        for entry in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = entry.path();
            let name = entry.file_name();
            let skip = name.to_string_lossy().starts_with('.')
                || [
                    "target", "src", "tests", "benches", "corpus", "tasks", "docs",
                ]
                .iter()
                .any(|s| name == *s);
            if p.is_dir() && !skip {
                stack.push(p);
            }
        }
    }
    out.sort();
    out
}

fn crate_name(dir: &Path) -> String {
    let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap();
    let package = manifest.split("[package]").nth(1).unwrap();
    let line = package
        .lines()
        .find(|l| l.trim_start().starts_with("name"))
        .unwrap();
    line.split('"').nth(1).unwrap().to_string()
}

/// Every `.rs` file under `src` but the binaries' roots (`main.rs` beside a `lib.rs`, and
/// `src/bin/`), which are crates of their own, as (path relative to `src`, text).
fn source_files(src: &Path) -> Vec<(PathBuf, String)> {
    let has_lib = src.join("lib.rs").is_file();
    let mut out = Vec::new();
    let mut stack = vec![src.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = entry.path();
            let rel = p.strip_prefix(src).unwrap().to_path_buf();
            if p.is_dir() {
                if rel != Path::new("bin") {
                    stack.push(p);
                }
            } else if p.extension().is_some_and(|e| e == "rs")
                && !(has_lib && rel == Path::new("main.rs"))
            {
                out.push((rel, std::fs::read_to_string(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// The module a file under `src/` holds, as `a::b` (the crate root is the empty string).
fn module_of(rel: &Path) -> String {
    let mut segs: Vec<String> = rel
        .iter()
        .map(|s| s.to_string_lossy().into_owned())
        .collect();
    let last = segs.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if !matches!(stem, "mod" | "lib" | "main") {
        segs.push(stem.to_string());
    }
    segs.join("::")
}

/// Every module's file and the modules whose files its code names, with one path that
/// leads there (for the message).
type Graph = BTreeMap<String, BTreeMap<String, String>>;

fn module_graph(files: &[(PathBuf, String)]) -> Graph {
    let modules: BTreeSet<String> = files.iter().map(|(p, _)| module_of(p)).collect();
    let mut graph = Graph::new();
    for (path, text) in files {
        let from = module_of(path);
        if from.is_empty() {
            continue; // the crate root: see the module comment
        }
        let edges = graph.entry(from.clone()).or_default();
        for (scope, children, segs) in paths(&tokens(text), &from) {
            let abs = match segs[0].as_str() {
                "crate" | "$crate" => segs[1..].to_vec(),
                "self" | "super" => {
                    let mut at: Vec<String> = split(&scope);
                    let mut rest = &segs[..];
                    while let Some(first) = rest.first() {
                        match first.as_str() {
                            "self" => {}
                            "super" => {
                                at.pop();
                            }
                            _ => break,
                        }
                        rest = &rest[1..];
                    }
                    at.extend(rest.iter().cloned());
                    at
                }
                child if children.contains(child) => {
                    let mut at = split(&scope);
                    at.extend(segs.iter().cloned());
                    at
                }
                _ => continue,
            };
            let target = (0..=abs.len())
                .rev()
                .map(|k| abs[..k].join("::"))
                .find(|m| modules.contains(m))
                .unwrap_or_default();
            if target != from && !target.is_empty() {
                edges.entry(target).or_insert_with(|| segs.join("::"));
            }
        }
    }
    graph
}

fn split(module: &str) -> Vec<String> {
    if module.is_empty() {
        Vec::new()
    } else {
        module.split("::").map(String::from).collect()
    }
}

/// The strongly connected sets of two or more modules (Tarjan's algorithm), leaving out the
/// edges between each pair in `skip`.
fn circles(graph: &Graph, skip: &[(&str, &str)]) -> Vec<BTreeSet<String>> {
    let names: Vec<&String> = graph.keys().collect();
    let index_of: BTreeMap<&str, usize> = names
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i))
        .collect();
    let skipped = |a: &str, b: &str| {
        skip.iter()
            .any(|&(x, y)| (x == a && y == b) || (x == b && y == a))
    };
    let succ: Vec<Vec<usize>> = names
        .iter()
        .map(|n| {
            graph[*n]
                .keys()
                .filter(|t| !skipped(n, t))
                .filter_map(|t| index_of.get(t.as_str()).copied())
                .collect()
        })
        .collect();
    struct Tarjan<'a> {
        succ: &'a [Vec<usize>],
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: Vec<Vec<usize>>,
    }
    impl Tarjan<'_> {
        fn visit(&mut self, v: usize) {
            self.index[v] = Some(self.next);
            self.low[v] = self.next;
            self.next += 1;
            self.stack.push(v);
            self.on_stack[v] = true;
            for &w in &self.succ[v] {
                match self.index[w] {
                    None => {
                        self.visit(w);
                        self.low[v] = self.low[v].min(self.low[w]);
                    }
                    Some(iw) if self.on_stack[w] => self.low[v] = self.low[v].min(iw),
                    Some(_) => {}
                }
            }
            if Some(self.low[v]) == self.index[v] {
                let mut set = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on_stack[w] = false;
                    set.push(w);
                    if w == v {
                        break;
                    }
                }
                self.out.push(set);
            }
        }
    }
    let n = names.len();
    let mut t = Tarjan {
        succ: &succ,
        index: vec![None; n],
        low: vec![0; n],
        on_stack: vec![false; n],
        stack: Vec::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in 0..n {
        if t.index[v].is_none() {
            t.visit(v);
        }
    }
    t.out
        .into_iter()
        .filter(|s| s.len() > 1)
        .map(|s| s.into_iter().map(|i| names[i].clone()).collect())
        .collect()
}

/// A circle's modules and, for each edge inside it, one path that makes it.
fn describe(graph: &Graph, circle: &BTreeSet<String>) -> String {
    let name = |m: &str| {
        if m.is_empty() {
            "(crate root)".to_string()
        } else {
            m.to_string()
        }
    };
    let mut edges = Vec::new();
    for a in circle {
        for (b, via) in &graph[a] {
            if circle.contains(b) {
                edges.push(format!("{} -> {} (`{via}`)", name(a), name(b)));
            }
        }
    }
    format!("circle {}", edges.join(", "))
}

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    /// `::`
    Path,
    Punct(char),
}

/// The file's tokens that matter for paths: identifiers (keywords included), `::` and single
/// punctuation; comments, string, char and number literals and lifetimes are dropped.
fn tokens(text: &str) -> Vec<Tok> {
    let c: Vec<char> = text.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    let at = |i: usize| c.get(i).copied().unwrap_or('\0');
    while i < c.len() {
        let ch = c[i];
        if ch.is_whitespace() {
            i += 1;
        } else if ch == '/' && at(i + 1) == '/' {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if ch == '/' && at(i + 1) == '*' {
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && at(i + 1) == '*' {
                    depth += 1;
                    i += 2;
                } else if c[i] == '*' && at(i + 1) == '/' {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if let Some(len) = raw_string_len(&c[i..]) {
            i += len;
        } else if ch == '"' || ((ch == 'b' || ch == 'c') && at(i + 1) == '"') {
            i += if ch == '"' { 1 } else { 2 };
            while i < c.len() && c[i] != '"' {
                i += if c[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
        } else if ch == '\'' || (ch == 'b' && at(i + 1) == '\'') {
            if ch == 'b' {
                i += 1;
            }
            if at(i + 1) == '\\' {
                i += 2;
                while i < c.len() && c[i] != '\'' {
                    i += 1;
                }
                i += 1;
            } else if at(i + 2) == '\'' {
                i += 3;
            } else {
                // A lifetime or label: the quote and its name.
                i += 1;
                while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                    i += 1;
                }
            }
        } else if ch.is_ascii_digit() {
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                i += 1;
            }
        } else if ch.is_alphabetic() || ch == '_' || (ch == '$' && at(i + 1).is_alphabetic()) {
            let start = i;
            i += 1;
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                i += 1;
            }
            let word: String = c[start..i].iter().collect();
            match word.strip_prefix("r#") {
                Some(w) => out.push(Tok::Ident(w.to_string())),
                None => out.push(Tok::Ident(word)),
            }
        } else if ch == ':' && at(i + 1) == ':' {
            out.push(Tok::Path);
            i += 2;
        } else {
            out.push(Tok::Punct(ch));
            i += 1;
        }
    }
    out
}

/// The length of a raw (byte or C) string literal starting at `c[0]`, if one does.
fn raw_string_len(c: &[char]) -> Option<usize> {
    let mut i = match (c.first(), c.get(1)) {
        (Some('r'), _) => 1,
        (Some('b' | 'c'), Some('r')) => 2,
        _ => return None,
    };
    let hashes = c[i..].iter().take_while(|&&x| x == '#').count();
    i += hashes;
    if c.get(i) != Some(&'"') {
        return None;
    }
    i += 1;
    while i < c.len() {
        if c[i] == '"'
            && c[i + 1..]
                .iter()
                .take(hashes)
                .filter(|&&x| x == '#')
                .count()
                == hashes
        {
            return Some(i + 1 + hashes);
        }
        i += 1;
    }
    Some(c.len())
}

/// Every module path the tokens name, with the (inline) module it is named in and that
/// module's declared children: `use` trees expanded, and paths in the code that start with
/// `crate`, `$crate`, `self`, `super` or a child module, followed by `::`.
fn paths(toks: &[Tok], file_module: &str) -> Vec<(String, BTreeSet<String>, Vec<String>)> {
    let ident = |i: usize| match toks.get(i) {
        Some(Tok::Ident(s)) => Some(s.as_str()),
        _ => None,
    };
    let children = child_modules(toks, file_module);
    // The inline module stack: (module path, brace depth its body opened at, its children).
    let top = children.get(file_module).cloned().unwrap_or_default();
    let mut scopes: Vec<(String, usize, BTreeSet<String>)> =
        vec![(file_module.to_string(), 0, top)];
    let mut out = Vec::new();
    let mut depth = 0;
    let mut i = 0;
    while i < toks.len() {
        let (scope, _, kids) = scopes.last().unwrap().clone();
        match &toks[i] {
            Tok::Punct('{') => {
                depth += 1;
                if ident(i.wrapping_sub(2)) == Some("mod") {
                    let path = join(&scope, ident(i - 1).unwrap());
                    let kids = children.get(&path).cloned().unwrap_or_default();
                    scopes.push((path, depth, kids));
                }
                i += 1;
            }
            Tok::Punct('}') => {
                if scopes.len() > 1 && scopes.last().unwrap().1 == depth {
                    scopes.pop();
                }
                depth -= 1;
                i += 1;
            }
            Tok::Ident(w) if w == "use" => {
                let mut found = Vec::new();
                i = use_tree(toks, i + 1, Vec::new(), &mut found);
                for p in found {
                    out.push((scope.clone(), kids.clone(), p));
                }
            }
            Tok::Ident(w)
                if toks.get(i + 1) == Some(&Tok::Path)
                    && i.checked_sub(1).is_none_or(|p| {
                        toks[p] != Tok::Path && toks[p] != Tok::Punct('.') && ident(p) != Some("in")
                    })
                    && (matches!(w.as_str(), "crate" | "$crate" | "self" | "super")
                        || kids.contains(w)) =>
            {
                let mut segs = vec![w.clone()];
                let mut j = i + 1;
                while toks.get(j) == Some(&Tok::Path) {
                    match ident(j + 1) {
                        Some(s) => segs.push(s.to_string()),
                        None => break,
                    }
                    j += 2;
                }
                out.push((scope.clone(), kids.clone(), segs));
                i = j;
            }
            _ => i += 1,
        }
    }
    out
}

/// The modules each (inline) module of the file declares (`mod x;` or `mod x { .. }`),
/// wherever in its body: a path may name a child declared further down.
fn child_modules(toks: &[Tok], file_module: &str) -> BTreeMap<String, BTreeSet<String>> {
    let ident = |i: usize| match toks.get(i) {
        Some(Tok::Ident(s)) => Some(s.as_str()),
        _ => None,
    };
    let mut children: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut stack = vec![(file_module.to_string(), 0usize)];
    let mut depth = 0;
    for (i, tok) in toks.iter().enumerate() {
        match tok {
            Tok::Punct('{') => {
                depth += 1;
                if ident(i.wrapping_sub(2)) == Some("mod") {
                    let name = ident(i - 1).unwrap();
                    let path = join(&stack.last().unwrap().0, name);
                    stack.push((path, depth));
                }
            }
            Tok::Punct('}') => {
                if stack.len() > 1 && stack.last().unwrap().1 == depth {
                    stack.pop();
                }
                depth -= 1;
            }
            Tok::Ident(m) if m == "mod" => {
                if let Some(name) = ident(i + 1) {
                    let scope = stack.last().unwrap().0.clone();
                    children.entry(scope).or_default().insert(name.to_string());
                }
            }
            _ => {}
        }
    }
    children
}

fn join(scope: &str, name: &str) -> String {
    if scope.is_empty() {
        name.to_string()
    } else {
        format!("{scope}::{name}")
    }
}

/// Expands the `use` tree starting at `toks[i]` under `prefix` into `out`; returns the index
/// after it (after the `;` at the top level).
fn use_tree(toks: &[Tok], mut i: usize, prefix: Vec<String>, out: &mut Vec<Vec<String>>) -> usize {
    let mut path = prefix;
    if toks.get(i) == Some(&Tok::Path) {
        i += 1; // `use ::std::...`
    }
    loop {
        match toks.get(i) {
            Some(Tok::Ident(s)) if s == "as" => i += 2,
            Some(Tok::Ident(s)) if s == "self" && !path.is_empty() => i += 1,
            Some(Tok::Ident(s)) => {
                path.push(s.clone());
                i += 1;
            }
            Some(Tok::Path) => i += 1,
            Some(Tok::Punct('{')) => {
                i += 1;
                while toks.get(i).is_some_and(|t| *t != Tok::Punct('}')) {
                    i = use_tree(toks, i, path.clone(), out);
                    if toks.get(i) == Some(&Tok::Punct(',')) {
                        i += 1;
                    }
                }
                i += 1;
                if toks.get(i) == Some(&Tok::Punct(';')) {
                    i += 1;
                }
                return i;
            }
            Some(Tok::Punct('*')) => i += 1,
            Some(Tok::Punct(',')) | Some(Tok::Punct('}')) => {
                if !path.is_empty() {
                    out.push(path);
                }
                return i;
            }
            Some(Tok::Punct(';')) | None => {
                if !path.is_empty() {
                    out.push(path);
                }
                return i + 1;
            }
            Some(Tok::Punct(_)) => i += 1,
        }
    }
}
