//! The imports between a crate's files, read from the source text: which module names which.
//!
//! A file is a module (`a/mod.rs` and `a.rs` are `a`, `lib.rs` the crate root). Module `m` uses
//! module `t` when its code names `t` by a path: a `use` tree (`crate::`, `super::`, `self::`, a
//! child module, or the crate's own name) or a `crate::` / `super::` / `self::` / child path in
//! the code. The path resolves to the deepest module it spells; what it names inside that file
//! does not matter. Comments, string and character literals and `#[cfg(test)]` items are left out
//! (tests sit on top of the code they test). A module naming one of its own ancestors is not an
//! edge: a file sits inside its parent, and the parent's re-exports are the tree, not a circle.
//! The binary roots (`main.rs`, `bin/`) are other crates and are not read.
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A module path inside its crate: `[]` is the root, `["train", "fit"]` is `train/fit.rs`.
pub type Module = Vec<String>;

/// The crate's library modules, each with its file.
pub fn modules(src: &Path) -> BTreeMap<Module, PathBuf> {
    let mut out = BTreeMap::new();
    walk(src, src, &mut out);
    out
}

fn walk(src: &Path, dir: &Path, out: &mut BTreeMap<Module, PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("a directory entry").path())
        .collect();
    entries.sort();
    for p in entries {
        let rel = p.strip_prefix(src).expect("below src");
        if p.is_dir() {
            if rel != Path::new("bin") {
                walk(src, &p, out);
            }
            continue;
        }
        if p.extension().and_then(|e| e.to_str()) != Some("rs") || rel == Path::new("main.rs") {
            continue;
        }
        let mut m: Module = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
        let last = m.pop().expect("a file name");
        match last.as_str() {
            "lib.rs" | "mod.rs" => {}
            f => m.push(f.trim_end_matches(".rs").to_string()),
        }
        out.insert(m, p);
    }
}

/// The source without comments, without the contents of string and char literals, and without
/// the items under `#[cfg(test)]`.
pub fn code_of(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < c.len() {
        let at = |k: usize| c.get(k).copied().unwrap_or('\0');
        if c[i] == '/' && at(i + 1) == '/' {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if c[i] == '/' && at(i + 1) == '*' {
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
            out.push(' ');
        } else if c[i] == 'r' && (at(i + 1) == '"' || (at(i + 1) == '#' && matches!(at(i + 2), '"' | '#')))
            && !(i > 0 && (c[i - 1].is_alphanumeric() || c[i - 1] == '_'))
        {
            // A raw string: r"..." or r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while at(j) == '#' {
                hashes += 1;
                j += 1;
            }
            j += 1;
            loop {
                if j >= c.len() {
                    break;
                }
                if c[j] == '"' && (0..hashes).all(|h| at(j + 1 + h) == '#') {
                    j += 1 + hashes;
                    break;
                }
                j += 1;
            }
            out.push_str("\"\"");
            i = j;
        } else if c[i] == '"' {
            i += 1;
            while i < c.len() && c[i] != '"' {
                i += if c[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if c[i] == '\'' {
            // A char literal ('x', '\n', '\''), or a lifetime ('a), which stays.
            if at(i + 1) == '\\' {
                let mut j = i + 2;
                while j < c.len() && c[j] != '\'' {
                    j += 1;
                }
                i = j + 1;
                out.push_str("' '");
            } else if at(i + 2) == '\'' {
                i += 3;
                out.push_str("' '");
            } else {
                out.push('\'');
                i += 1;
            }
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    without_tests(&out)
}

/// `code` less each item that follows `#[cfg(test)]` (to its `;` or its closing brace).
fn without_tests(code: &str) -> String {
    let mut out = String::new();
    let mut rest = code;
    while let Some(k) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..k]);
        let item = &rest[k..];
        let mut depth = 0usize;
        let mut end = item.len();
        for (j, ch) in item.char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => {
                    depth = depth.saturating_sub(1);
                    if depth == 0 {
                        end = j + 1;
                        break;
                    }
                }
                ';' if depth == 0 => {
                    end = j + 1;
                    break;
                }
                _ => {}
            }
        }
        rest = &item[end..];
    }
    out.push_str(rest);
    out
}

/// Every path the code spells, as segments: each leaf of each `use` tree, and each run of
/// `ident::ident...` elsewhere (starting where no `::` or identifier comes before it).
pub fn paths(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let mut rest = code;
    // `use` trees first; their text is then blanked so the path scan below does not read them twice.
    let mut plain = String::new();
    while let Some(k) = find_word(rest, "use") {
        plain.push_str(&rest[..k]);
        let tail = &rest[k + 3..];
        let end = tail.find(';').unwrap_or(tail.len());
        use_tree(tail[..end].trim(), &[], &mut out);
        rest = &tail[(end + 1).min(tail.len())..];
    }
    plain.push_str(rest);
    let b = plain.as_bytes();
    let ident = |ch: u8| ch.is_ascii_alphanumeric() || ch == b'_';
    let mut i = 0;
    while i < b.len() {
        if ident(b[i]) && (i == 0 || !(ident(b[i - 1]) || (i >= 2 && &b[i - 2..i] == b"::"))) {
            let mut segs = Vec::new();
            let mut j = i;
            loop {
                let s = j;
                while j < b.len() && ident(b[j]) {
                    j += 1;
                }
                segs.push(plain[s..j].to_string());
                if plain[j..].starts_with("::") && plain[j + 2..].starts_with(|ch: char| ch.is_alphanumeric() || ch == '_') {
                    j += 2;
                } else {
                    break;
                }
            }
            if segs.len() > 1 {
                out.push(segs);
            }
            i = j.max(i + 1);
        } else {
            i += 1;
        }
    }
    out
}

/// Where `word` stands alone in `s` (not inside a longer identifier).
fn find_word(s: &str, word: &str) -> Option<usize> {
    let b = s.as_bytes();
    let ident = |ch: u8| ch.is_ascii_alphanumeric() || ch == b'_';
    let mut from = 0;
    while let Some(k) = s[from..].find(word).map(|k| k + from) {
        let before = k == 0 || !ident(b[k - 1]);
        let after = b.get(k + word.len()).is_none_or(|&ch| !ident(ch));
        if before && after {
            return Some(k);
        }
        from = k + word.len();
    }
    None
}

/// The leaves of a `use` tree (`a::b::{c, d::{e, f}}`, `a::*`, `a as b`), each prefixed.
fn use_tree(tree: &str, prefix: &[String], out: &mut Vec<Vec<String>>) {
    let tree = tree.trim();
    if tree.is_empty() {
        return;
    }
    let tree = tree.split(" as ").next().unwrap_or(tree).trim();
    if let Some(open) = tree.find('{') {
        let head: Vec<String> = tree[..open].split("::").map(str::trim).filter(|s| !s.is_empty()).map(String::from).collect();
        let mut p = prefix.to_vec();
        p.extend(head);
        let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
        let mut depth = 0;
        let mut start = 0;
        for (j, ch) in inner.char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    use_tree(&inner[start..j], &p, out);
                    start = j + 1;
                }
                _ => {}
            }
        }
        use_tree(&inner[start..], &p, out);
    } else {
        let mut p = prefix.to_vec();
        p.extend(tree.split("::").map(str::trim).filter(|s| !s.is_empty() && *s != "*").map(String::from));
        out.push(p);
    }
}

/// The module a path names from module `from`, if it is one of the crate's (`krate` is the
/// crate's own name, e.g. `msr_host`).
pub fn resolve(path: &[String], from: &Module, mods: &BTreeMap<Module, PathBuf>, krate: &str) -> Option<Module> {
    let mut segs = path.iter().peekable();
    let mut at: Module = match segs.peek()?.as_str() {
        "crate" => {
            segs.next();
            vec![]
        }
        k if k == krate => {
            segs.next();
            vec![]
        }
        "self" => {
            segs.next();
            from.clone()
        }
        "super" => {
            let mut m = from.clone();
            while segs.peek().map(|s| s.as_str()) == Some("super") {
                segs.next();
                m.pop()?;
            }
            m
        }
        first => {
            let mut child = from.clone();
            child.push(first.to_string());
            if !mods.contains_key(&child) {
                return None;
            }
            from.clone()
        }
    };
    for s in segs {
        if s == "self" {
            continue;
        }
        let mut next = at.clone();
        next.push(s.clone());
        if mods.contains_key(&next) {
            at = next;
        } else {
            break;
        }
    }
    Some(at)
}

/// The import graph of the crate in `src` (its name `krate`): each module and the modules it
/// names, less itself and its ancestors.
pub fn graph(src: &Path, krate: &str) -> BTreeMap<Module, BTreeSet<Module>> {
    let mods = modules(src);
    let mut g = BTreeMap::new();
    for (m, file) in &mods {
        let text = std::fs::read_to_string(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let mut to = BTreeSet::new();
        for p in paths(&code_of(&text)) {
            if let Some(t) = resolve(&p, m, &mods, krate) {
                if t != *m && !m.starts_with(&t) {
                    to.insert(t);
                }
            }
        }
        g.insert(m.clone(), to);
    }
    g
}

/// Every circle of the graph: each strongly connected set of two or more modules, given as one
/// shortest cycle through its first module followed by the whole set.
pub fn circles(g: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<(Vec<Module>, BTreeSet<Module>)> {
    let mut out = Vec::new();
    for scc in components(g) {
        if scc.len() < 2 {
            continue;
        }
        let start = scc.iter().next().expect("non-empty").clone();
        out.push((shortest_cycle(g, &start, &scc), scc));
    }
    out
}

/// Tarjan's strongly connected components.
fn components(g: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<BTreeSet<Module>> {
    struct T<'a> {
        g: &'a BTreeMap<Module, BTreeSet<Module>>,
        index: BTreeMap<&'a Module, usize>,
        low: BTreeMap<&'a Module, usize>,
        stack: Vec<&'a Module>,
        on: BTreeSet<&'a Module>,
        out: Vec<BTreeSet<Module>>,
    }
    fn visit<'a>(t: &mut T<'a>, v: &'a Module) {
        let n = t.index.len();
        t.index.insert(v, n);
        t.low.insert(v, n);
        t.stack.push(v);
        t.on.insert(v);
        let g = t.g;
        for w in g.get(v).into_iter().flatten() {
            let Some((w, _)) = g.get_key_value(w) else { continue };
            if !t.index.contains_key(w) {
                visit(t, w);
                let l = t.low[v].min(t.low[w]);
                t.low.insert(v, l);
            } else if t.on.contains(w) {
                let l = t.low[v].min(t.index[w]);
                t.low.insert(v, l);
            }
        }
        if t.low[v] == t.index[v] {
            let mut scc = BTreeSet::new();
            while let Some(w) = t.stack.pop() {
                t.on.remove(w);
                scc.insert(w.clone());
                if w == v {
                    break;
                }
            }
            t.out.push(scc);
        }
    }
    let mut t = T { g, index: BTreeMap::new(), low: BTreeMap::new(), stack: vec![], on: BTreeSet::new(), out: vec![] };
    for v in g.keys() {
        if !t.index.contains_key(v) {
            visit(&mut t, v);
        }
    }
    t.out
}

/// A shortest path from `start` back to itself inside `within` (breadth first).
fn shortest_cycle(g: &BTreeMap<Module, BTreeSet<Module>>, start: &Module, within: &BTreeSet<Module>) -> Vec<Module> {
    let mut prev: BTreeMap<Module, Module> = BTreeMap::new();
    let mut queue = std::collections::VecDeque::from([start.clone()]);
    while let Some(v) = queue.pop_front() {
        for w in g.get(&v).into_iter().flatten().filter(|w| within.contains(*w)) {
            if w == start {
                let mut path = vec![v.clone()];
                while let Some(p) = prev.get(path.last().expect("non-empty")) {
                    path.push(p.clone());
                }
                path.reverse();
                path.push(start.clone());
                return path;
            }
            if !prev.contains_key(w) && w != start {
                prev.insert(w.clone(), v.clone());
                queue.push_back(w.clone());
            }
        }
    }
    vec![start.clone()]
}

/// The file of each module of `g` that names a module under `forbidden` (e.g. `["cmd"]`), unless
/// it sits under `forbidden` itself.
pub fn naming(g: &BTreeMap<Module, BTreeSet<Module>>, forbidden: &[&str]) -> Vec<(Module, Module)> {
    let under = |m: &Module| m.len() >= forbidden.len() && m.iter().zip(forbidden).all(|(a, b)| a == b);
    let mut out = Vec::new();
    for (m, to) in g {
        if under(m) {
            continue;
        }
        for t in to.iter().filter(|t| under(t)) {
            out.push((m.clone(), t.clone()));
        }
    }
    out
}

/// A module as the file it is in, for messages.
pub fn show(m: &Module) -> String {
    if m.is_empty() {
        "crate".into()
    } else {
        m.join("::")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The crates whose imports must run one way: (folder, crate name in paths).
    const CRATES: [(&str, &str); 4] = [("host", "msr_host"), ("sim", "msr_sim"), ("firmware", "msr_firmware"), ("shared", "msr_shared")];

    fn src(krate: &str) -> PathBuf {
        crate::root().join(krate).join("src")
    }

    #[test]
    fn the_host_library_never_names_its_commands() {
        let g = graph(&src("host"), "msr_host");
        let bad: Vec<String> = naming(&g, &["cmd"]).iter().map(|(m, t)| format!("{} names {}", show(m), show(t))).collect();
        assert!(bad.is_empty(), "library modules outside cmd/ that use it: {bad:#?}");
    }

    #[test]
    fn no_circle_of_imports() {
        let mut found = Vec::new();
        for (dir, name) in CRATES {
            for (cycle, set) in circles(&graph(&src(dir), name)) {
                let c: Vec<String> = cycle.iter().map(show).collect();
                let s: Vec<String> = set.iter().map(show).collect();
                found.push(format!("{dir}: {} (all of: {})", c.join(" -> "), s.join(", ")));
            }
        }
        assert!(found.is_empty(), "circles of imports:\n{}", found.join("\n"));
    }

    /// A crate written into a temporary folder, to test the checker on circles it must find.
    fn fixture(files: &[(&str, &str)]) -> tempdir::Dir {
        let d = tempdir::Dir::new();
        for (p, text) in files {
            let p = d.0.join(p);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, text).unwrap();
        }
        d
    }

    mod tempdir {
        pub struct Dir(pub std::path::PathBuf);
        impl Dir {
            pub fn new() -> Self {
                use std::sync::atomic::{AtomicUsize, Ordering};
                static N: AtomicUsize = AtomicUsize::new(0);
                let p = std::env::temp_dir()
                    .join(format!("xtask-imports-{}-{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed)));
                let _ = std::fs::remove_dir_all(&p);
                std::fs::create_dir_all(&p).unwrap();
                Dir(p)
            }
        }
        impl Drop for Dir {
            fn drop(&mut self) {
                let _ = std::fs::remove_dir_all(&self.0);
            }
        }
    }

    #[test]
    fn finds_the_circles_and_the_upward_names_it_must() {
        let d = fixture(&[
            ("lib.rs", "pub mod cmd; pub mod a; pub mod b; pub mod c;\n"),
            ("cmd/mod.rs", "pub fn usage(_: &str) {}\n"),
            // A use tree with braces and a path in code: a -> b, a -> cmd.
            ("a.rs", "use crate::{b::{self, Thing}, x};\npub fn go() { crate::cmd::usage(\"crate::c\"); }\n"),
            // Only a comment, a string and a test name c; the code names a through super.
            ("b.rs", "// crate::c::f()\nconst S: &str = \"crate::c\";\nfn f() { super::a::go() }\n#[cfg(test)]\nmod tests { use crate::c; }\n"),
            ("c.rs", "use super::b;\n"),
        ]);
        let g = graph(&d.0, "k");
        let m = |s: &str| s.split("::").map(String::from).collect::<Module>();
        assert_eq!(g[&m("a")], BTreeSet::from([m("b"), m("cmd")]));
        assert_eq!(g[&m("b")], BTreeSet::from([m("a")]));
        assert_eq!(naming(&g, &["cmd"]), vec![(m("a"), m("cmd"))]);
        let c = circles(&g);
        assert_eq!(c.len(), 1, "{c:?}");
        assert_eq!(c[0].1, BTreeSet::from([m("a"), m("b")]));
        assert_eq!(c[0].0, vec![m("a"), m("b"), m("a")]);
    }
}
