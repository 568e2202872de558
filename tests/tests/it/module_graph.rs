//! The modules' import graph of every crate: no import circles (a module reaching itself through
//! the `crate::`, `super::`, `self::` and child-module paths of its code, the tests at its foot
//! left out; a parent's paths into its own children are its tree, not imports), and in the host,
//! imports only downwards through its layers: commands → the station → workflows → libraries
//! (`io`, `link`, `simulate`, `report`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The crates whose modules are checked, relative to the workspace.
const CRATES: [&str; 6] = ["shared", "firmware", "calib", "measure", "surface", "host"];

/// The host's layers, highest first: a module may import its own layer and those below.
const HOST_LAYERS: [&[&str]; 4] = [
    &["commands"],
    &["station"],
    &["workflows"],
    &["io", "link", "simulate", "report"],
];

/// One crate's modules: module path ("" the root, "a::b") → its file and the modules it uses.
type Graph = BTreeMap<String, (PathBuf, BTreeSet<String>)>;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The `.rs` files of a crate's `src/` with their module paths (binaries left out: `main.rs`
/// and `bin/` are crate roots of their own, over the library's public paths).
fn modules(src: &Path) -> Vec<(String, PathBuf)> {
    let mut out = Vec::new();
    let mut dirs = vec![src.to_path_buf()];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let rel = path.strip_prefix(src).unwrap().to_path_buf();
            if path.is_dir() {
                if rel != Path::new("bin") {
                    dirs.push(path);
                }
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") || rel == Path::new("main.rs") {
                continue;
            }
            let mut parts: Vec<String> = rel
                .with_extension("")
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            if matches!(parts.last().map(String::as_str), Some("mod" | "lib")) {
                parts.pop();
            }
            out.push((parts.join("::"), path));
        }
    }
    out
}

/// The code of a file without its comments and string literals, and without the tests at its
/// foot (from the first `#[cfg(test)]` or `#[cfg(all(test, …))]` line on).
fn code(text: &str) -> String {
    let foot = ["\n#[cfg(test)]", "\n#[cfg(all(test"]
        .iter()
        .filter_map(|t| text.find(t))
        .min();
    let text = &text[..foot.unwrap_or(text.len())];
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '/' if chars.peek() == Some(&'/') => {
                for c in chars.by_ref() {
                    if c == '\n' {
                        out.push('\n');
                        break;
                    }
                }
            }
            '"' => {
                while let Some(c) = chars.next() {
                    match c {
                        '\\' => {
                            chars.next();
                        }
                        '"' => break,
                        _ => {}
                    }
                }
                out.push_str("\"\"");
            }
            // A char literal ('"' included); lifetimes pass through unchanged.
            '\'' => {
                let mut lookahead = chars.clone();
                let literal = matches!(
                    (lookahead.next(), lookahead.next()),
                    (Some('\\'), _) | (Some(_), Some('\''))
                );
                if literal {
                    for c in chars.by_ref() {
                        if c == '\'' {
                            break;
                        }
                    }
                    out.push_str("' '");
                } else {
                    out.push(c);
                }
            }
            _ => out.push(c),
        }
    }
    out
}

/// Every path the code names: the full paths of its `use` trees (braces expanded) and the
/// other `a::b::c` paths, as segments.
fn paths(code: &str) -> Vec<Vec<String>> {
    let tokens = tokenize(code);
    let mut out = Vec::new();
    let mut i = 0;
    while i < tokens.len() {
        if tokens[i] == "use" {
            i += 1;
            use_tree(&tokens, &mut i, &mut Vec::new(), &mut out);
            continue;
        }
        if is_ident(&tokens[i]) && (i == 0 || tokens[i - 1] != "::") {
            let mut path = vec![tokens[i].clone()];
            let mut j = i + 1;
            while j + 1 < tokens.len() && tokens[j] == "::" && is_ident(&tokens[j + 1]) {
                path.push(tokens[j + 1].clone());
                j += 2;
            }
            if path.len() > 1 {
                out.push(path);
            }
            i = j;
            continue;
        }
        i += 1;
    }
    out
}

/// A `use` tree from `tokens[*i]` on, its paths (after `prefix`) into `out`.
fn use_tree(
    tokens: &[String],
    i: &mut usize,
    prefix: &mut Vec<String>,
    out: &mut Vec<Vec<String>>,
) {
    let depth = prefix.len();
    loop {
        match tokens.get(*i).map(String::as_str) {
            Some("{") => {
                *i += 1;
                loop {
                    use_tree(tokens, i, prefix, out);
                    match tokens.get(*i).map(String::as_str) {
                        Some(",") => *i += 1,
                        Some("}") => {
                            *i += 1;
                            break;
                        }
                        _ => break,
                    }
                    if tokens.get(*i).map(String::as_str) == Some("}") {
                        *i += 1;
                        break;
                    }
                }
                prefix.truncate(depth);
                return;
            }
            Some(t) if is_ident(t) => {
                prefix.push(t.to_owned());
                *i += 1;
                if tokens.get(*i).map(String::as_str) == Some("::") {
                    *i += 1;
                    continue;
                }
                if tokens.get(*i).map(String::as_str) == Some("as") {
                    *i += 2;
                }
                out.push(prefix.clone());
                prefix.truncate(depth);
                return;
            }
            Some("*") => {
                *i += 1;
                out.push(prefix.clone());
                prefix.truncate(depth);
                return;
            }
            _ => {
                prefix.truncate(depth);
                return;
            }
        }
    }
}

fn is_ident(t: &str) -> bool {
    t.chars()
        .next()
        .is_some_and(|c| c.is_alphabetic() || c == '_')
}

/// Identifiers, `::` and single punctuation characters.
fn tokenize(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let chars: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if c.is_alphanumeric() || c == '_' {
            let start = i;
            while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
                i += 1;
            }
            out.push(chars[start..i].iter().collect());
        } else if c == ':' && chars.get(i + 1) == Some(&':') {
            out.push("::".to_owned());
            i += 2;
        } else {
            if !c.is_whitespace() {
                out.push(c.to_string());
            }
            i += 1;
        }
    }
    out
}

/// The module a path names from module `at`: the longest known module its absolute form starts
/// with, or `None` for another crate's path.
fn resolve(at: &str, path: &[String], known: &BTreeSet<String>) -> Option<String> {
    let mut current: Vec<&str> = if at.is_empty() {
        Vec::new()
    } else {
        at.split("::").collect()
    };
    let mut rest = path.iter().map(String::as_str).peekable();
    match rest.peek().copied() {
        Some("crate") => {
            current.clear();
            rest.next();
        }
        Some("self") => {
            rest.next();
        }
        Some("super") => {
            while rest.peek() == Some(&"super") {
                current.pop()?;
                rest.next();
            }
        }
        Some(first) => {
            let child = [current.as_slice(), &[first]].concat().join("::");
            if !known.contains(&child) {
                return None;
            }
        }
        None => return None,
    }
    let mut best = current.join("::");
    for segment in rest {
        current.push(segment);
        let candidate = current.join("::");
        if known.contains(&candidate) {
            best = candidate;
        } else {
            break;
        }
    }
    Some(best)
}

/// `module` is `parent` or lies inside it: a parent reaching into its own children (to re-export
/// or call them) is its tree, not an import; children using their parent's items are edges.
fn within(module: &str, parent: &str) -> bool {
    parent.is_empty()
        || module == parent
        || module
            .strip_prefix(parent)
            .is_some_and(|rest| rest.starts_with("::"))
}

fn graph(krate: &str) -> Graph {
    let src = workspace().join(krate).join("src");
    let files = modules(&src);
    let known: BTreeSet<String> = files.iter().map(|(m, _)| m.clone()).collect();
    files
        .into_iter()
        .map(|(module, path)| {
            let text = std::fs::read_to_string(&path).unwrap();
            let uses = paths(&code(&text))
                .iter()
                .filter_map(|p| resolve(&module, p, &known))
                .filter(|target| !within(target, &module))
                .collect();
            (module, (path, uses))
        })
        .collect()
}

/// The strongly connected components of more than one module (Tarjan).
fn circles(graph: &Graph) -> Vec<Vec<String>> {
    struct State<'a> {
        graph: &'a Graph,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on_stack: BTreeSet<&'a str>,
        found: Vec<Vec<String>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a str) {
        let n = s.index.len();
        s.index.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in &s.graph[v].1 {
            let w = w.as_str();
            if !s.index.contains_key(w) {
                visit(s, w);
                let low = s.low[v].min(s.low[w]);
                s.low.insert(v, low);
            } else if s.on_stack.contains(w) {
                let low = s.low[v].min(s.index[w]);
                s.low.insert(v, low);
            }
        }
        if s.low[v] == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack.remove(w);
                component.push(w.to_owned());
                if w == v {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                s.found.push(component);
            }
        }
    }
    let mut state = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        found: Vec::new(),
    };
    for v in graph.keys() {
        if !state.index.contains_key(v.as_str()) {
            visit(&mut state, v);
        }
    }
    state.found
}

/// The checker reads paths, resolves them to modules and finds circles as it should: a tiny
/// graph with one circle, another with none.
#[test]
fn circles_are_found_in_a_known_graph() {
    let text = "use crate::a::{b::Item, c};\nfn f() { super::d::g(); self::e::h(); x::y(); }";
    let found = paths(&code(text));
    assert!(found.contains(&vec!["crate".into(), "a".into(), "b".into(), "Item".into()]));
    assert!(found.contains(&vec!["crate".into(), "a".into(), "c".into()]));
    assert!(found.contains(&vec!["super".into(), "d".into(), "g".into()]));
    let known: BTreeSet<String> = ["a", "a::b", "a::c", "d", "k"].map(String::from).into();
    assert_eq!(resolve("k", &found[0], &known).as_deref(), Some("a::b"));
    assert_eq!(resolve("k", &found[2], &known).as_deref(), Some("d"));
    assert_eq!(resolve("k", &["x".into(), "y".into()], &known), None);
    let edges = |e: &[(&str, &[&str])]| -> Graph {
        e.iter()
            .map(|(m, to)| {
                let to = to.iter().map(|t| t.to_string()).collect();
                (m.to_string(), (PathBuf::new(), to))
            })
            .collect()
    };
    let g = edges(&[("a", &["b"]), ("b", &["c"]), ("c", &["a"]), ("d", &["a"])]);
    assert_eq!(circles(&g), vec![vec!["a", "b", "c"]]);
    assert!(circles(&edges(&[("a", &["b"]), ("b", &[]), ("c", &["a", "b"])])).is_empty());
    // Comments, strings and the tests at the foot are not code.
    let hidden =
        "// crate::a::x\nfn f() { \"crate::a\"; }\n#[cfg(test)]\nmod tests { use crate::a; }";
    assert!(paths(&code(hidden)).iter().all(|p| p[0] != "crate"));
}

#[test]
fn no_import_circles() {
    let mut found = Vec::new();
    for krate in CRATES {
        for circle in circles(&graph(krate)) {
            found.push(format!("{krate}: {}", circle.join(" ↔ ")));
        }
    }
    assert!(found.is_empty(), "import circles:\n{}", found.join("\n"));
}

#[test]
fn host_imports_only_downwards() {
    let layer = |module: &str| {
        let top = module.split("::").next().unwrap_or_default();
        HOST_LAYERS.iter().position(|l| l.contains(&top))
    };
    let g = graph("host");
    let mut upward = Vec::new();
    for (module, (path, uses)) in &g {
        let Some(own) = layer(module) else {
            continue;
        };
        for target in uses {
            if layer(target).is_some_and(|l| l < own) {
                upward.push(format!("{} ({module}) imports {target}", path.display()));
            }
        }
    }
    assert!(
        upward.is_empty(),
        "imports against the layers:\n{}",
        upward.join("\n")
    );
    // Every module of the host is in a layer (but the crate root).
    let unplaced: Vec<&String> = g
        .keys()
        .filter(|m| !m.is_empty() && layer(m).is_none())
        .collect();
    assert!(
        unplaced.is_empty(),
        "modules outside the layers: {unplaced:?}"
    );
}
