//! The house rules, checked on every test run so they are kept as the project grows: no written
//! file (code, docs, pipelines, scripts) over 700 lines, and no circle of imports between the files
//! of `src/`. The integration tests (`tests/it/`, one crate of modules since they share one binary)
//! are held to the second rule too.
//!
//! An import is any path a file names that leads into another file's module: `use` trees (braces
//! expanded), paths written inline in code (`crate::filters::noise::tone_level(..)`), `super::` paths and
//! paths through a child module. A `mod child;` declaration is not an import, but a parent's
//! `pub use child::X` is, and so is a child's `super::Y`: a folder's `mod.rs` and its files must
//! also use each other in one direction only.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

#[path = "shared/files.rs"]
mod files;
use files::written_files;

const MAX_LINES: usize = 700;

/// Every `.rs` file under `dir`, sorted.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    written_files(dir, &["rs"], out);
}

/// The module path of a file under a crate's folder whose root file is `root` (`src/lib.rs` → [],
/// `src/io/mod.rs` → ["io"], `src/io/pfm.rs` → ["io", "pfm"]); `None` for the folder's other crate
/// root (`src/main.rs`, the binary beside the library).
fn module_path(src: &Path, root: &str, file: &Path) -> Option<Vec<String>> {
    let rel = file.strip_prefix(src).unwrap();
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap();
    match last.as_str() {
        name if parts.is_empty() && name == root => Some(parts),
        "lib.rs" | "main.rs" if parts.is_empty() => None,
        "mod.rs" => Some(parts),
        name => {
            parts.push(name.trim_end_matches(".rs").to_string());
            Some(parts)
        }
    }
}

/// The text with comments, string and character literals blanked, so braces and paths in them
/// are not read as code.
fn code_only(text: &str) -> String {
    let b: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        let next = b.get(i + 1).copied();
        if c == '/' && next == Some('/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && next == Some('*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == '/' && b.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == '*' && b.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    if b[i] == '\n' {
                        out.push('\n');
                    }
                    i += 1;
                }
            }
        } else if c == 'r' && (next == Some('#') || next == Some('"')) && is_raw_start(&b, i) {
            let mut hashes = 0;
            i += 1;
            while b[i] == '#' {
                hashes += 1;
                i += 1;
            }
            i += 1; // the opening quote
            loop {
                if b[i] == '"' && (0..hashes).all(|k| b.get(i + 1 + k) == Some(&'#')) {
                    i += 1 + hashes;
                    break;
                }
                i += 1;
            }
            out.push_str("\"\"");
        } else if c == '"' {
            i += 1;
            while b[i] != '"' {
                if b[i] == '\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push_str("\"\"");
        } else if c == '\'' && is_char_literal(&b, i) {
            i += 1;
            while b[i] != '\'' {
                if b[i] == '\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push_str("' '");
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

/// `r"…"` or `r#"…"#` starting at `i`, not the end of an identifier such as `for`.
fn is_raw_start(b: &[char], i: usize) -> bool {
    if i > 0 && (b[i - 1].is_alphanumeric() || b[i - 1] == '_') {
        return false;
    }
    let mut j = i + 1;
    while b.get(j) == Some(&'#') {
        j += 1;
    }
    b.get(j) == Some(&'"')
}

/// A character literal (`'x'`, `'\n'`, `'\u{..}'`) at `i`, not a lifetime (`'a`).
fn is_char_literal(b: &[char], i: usize) -> bool {
    matches!(
        (b.get(i + 1), b.get(i + 2)),
        (Some('\\'), _) | (Some(_), Some('\''))
    )
}

/// Expands a `use` tree (`a::{b, c::{d, e}}`) into its paths.
fn expand_use(tree: &str) -> Vec<String> {
    let tree: String = tree.chars().filter(|c| !c.is_whitespace()).collect();
    let Some(open) = tree.find('{') else {
        return vec![tree.split(" as ").next().unwrap().to_string()];
    };
    let prefix = &tree[..open];
    let inner = &tree[open + 1..tree.rfind('}').unwrap()];
    let mut parts = Vec::new();
    let (mut depth, mut start) = (0, 0);
    for (k, c) in inner.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&inner[start..k]);
                start = k + 1;
            }
            _ => {}
        }
    }
    parts.push(&inner[start..]);
    parts
        .into_iter()
        .filter(|p| !p.is_empty())
        .flat_map(|p| {
            expand_use(p)
                .into_iter()
                .map(move |q| format!("{prefix}{q}"))
        })
        .collect()
}

/// The paths a file names, each with the inline module it is written in (`mod tests { .. }`),
/// as module-path segments relative to the file's own module.
fn named_paths(code: &str) -> Vec<(Vec<String>, Vec<String>)> {
    let mut found = Vec::new();
    // Inline modules open and close with braces; track which one each position is in.
    let chars: Vec<char> = code.chars().collect();
    let mut inline: Vec<(String, usize)> = Vec::new();
    let mut depth = 0usize;
    let mut i = 0;
    let word_at = |i: usize, w: &str| -> bool {
        let wc: Vec<char> = w.chars().collect();
        chars.len() >= i + wc.len()
            && chars[i..i + wc.len()] == wc[..]
            && (i == 0 || !(chars[i - 1].is_alphanumeric() || chars[i - 1] == '_'))
            && chars
                .get(i + wc.len())
                .is_none_or(|c| !(c.is_alphanumeric() || *c == '_'))
    };
    let inside = |inline: &[(String, usize)]| inline.iter().map(|(n, _)| n.clone()).collect();
    while i < chars.len() {
        let c = chars[i];
        if c == '{' {
            depth += 1;
            i += 1;
        } else if c == '}' {
            if inline.last().is_some_and(|(_, d)| *d == depth) {
                inline.pop();
            }
            depth -= 1;
            i += 1;
        } else if word_at(i, "mod") {
            // `mod name {` opens an inline module; `mod name;` declares a file.
            let rest: String = chars[i + 3..].iter().take(200).collect();
            let rest = rest.trim_start();
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            let after = rest[name.len()..].trim_start();
            if after.starts_with('{') {
                let open = i + 3 + chars[i + 3..].iter().position(|&c| c == '{').unwrap();
                depth += 1;
                inline.push((name, depth));
                i = open + 1;
            } else {
                i += 3;
            }
        } else if word_at(i, "use") {
            let end = i + chars[i..].iter().position(|&c| c == ';').unwrap();
            let tree: String = chars[i + 3..end].iter().collect();
            for path in expand_use(&tree) {
                let segs: Vec<String> = path
                    .trim_start_matches("::")
                    .split("::")
                    .map(String::from)
                    .collect();
                found.push((inside(&inline), segs));
            }
            i = end + 1;
        } else if c.is_alphabetic() || c == '_' {
            // An inline path: identifiers joined by `::`.
            if i > 0
                && (chars[i - 1].is_alphanumeric() || chars[i - 1] == '_' || chars[i - 1] == ':')
            {
                i += 1;
                continue;
            }
            let mut j = i;
            let mut segs = Vec::new();
            loop {
                let start = j;
                while j < chars.len() && (chars[j].is_alphanumeric() || chars[j] == '_') {
                    j += 1;
                }
                segs.push(chars[start..j].iter().collect::<String>());
                if chars.get(j) == Some(&':') && chars.get(j + 1) == Some(&':') {
                    let k = j + 2;
                    if chars.get(k).is_some_and(|c| c.is_alphabetic() || *c == '_') {
                        j = k;
                        continue;
                    }
                }
                break;
            }
            if segs.len() > 1 {
                found.push((inside(&inline), segs));
            }
            i = j.max(i + 1);
        } else {
            i += 1;
        }
    }
    found
}

/// The file a path leads into: the longest prefix of `segs` (made absolute from `here`, the
/// module the path is written in, and `children`, the modules declared there) that is a file.
fn resolve(
    here: &[String],
    segs: &[String],
    files: &BTreeMap<Vec<String>, PathBuf>,
) -> Option<PathBuf> {
    let mut abs: Vec<String> = match segs[0].as_str() {
        "crate" => vec![],
        "super" => {
            let mut m = here.to_vec();
            m.pop()?;
            m
        }
        "self" => here.to_vec(),
        _ => {
            // A child module of `here` (2018 paths), else an outside crate, a type or a local name.
            let mut child = here.to_vec();
            child.push(segs[0].clone());
            if !files.contains_key(&child) {
                return None;
            }
            here.to_vec()
        }
    };
    let rest = match segs[0].as_str() {
        "crate" | "self" => &segs[1..],
        "super" => {
            let mut k = 1;
            while segs.get(k).is_some_and(|s| s == "super") {
                abs.pop()?;
                k += 1;
            }
            &segs[k..]
        }
        _ => segs,
    };
    abs.extend(rest.iter().cloned());
    while !abs.is_empty() && !files.contains_key(&abs) {
        abs.pop();
    }
    files.get(&abs).cloned()
}

/// Every file's imports: the other files it names, in the crate whose root is `src/root`.
fn import_graph(src: &Path, root: &str) -> BTreeMap<PathBuf, BTreeSet<PathBuf>> {
    let mut all = Vec::new();
    rust_files(src, &mut all);
    let files: BTreeMap<Vec<String>, PathBuf> = all
        .iter()
        .filter_map(|f| module_path(src, root, f).map(|m| (m, f.clone())))
        .collect();
    let mut graph = BTreeMap::new();
    for (module, file) in &files {
        let code = code_only(&fs::read_to_string(file).unwrap());
        let mut edges = BTreeSet::new();
        for (inline, segs) in named_paths(&code) {
            let mut here = module.clone();
            here.extend(inline);
            if let Some(target) = resolve(&here, &segs, &files) {
                if &target != file {
                    edges.insert(target);
                }
            }
        }
        graph.insert(file.clone(), edges);
    }
    graph
}

/// The strongly connected groups of more than one file (Tarjan's algorithm).
fn circles(graph: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    struct State<'a> {
        graph: &'a BTreeMap<PathBuf, BTreeSet<PathBuf>>,
        index: BTreeMap<&'a PathBuf, usize>,
        low: BTreeMap<&'a PathBuf, usize>,
        stack: Vec<&'a PathBuf>,
        on_stack: BTreeSet<&'a PathBuf>,
        out: Vec<Vec<PathBuf>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a PathBuf) {
        let n = s.index.len();
        s.index.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in &s.graph[v] {
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut group = Vec::new();
            loop {
                let w = s.stack.pop().unwrap();
                s.on_stack.remove(w);
                group.push(w.clone());
                if w == v {
                    break;
                }
            }
            if group.len() > 1 {
                group.sort();
                s.out.push(group);
            }
        }
    }
    let mut s = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in graph.keys() {
        if !s.index.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn src() -> PathBuf {
    root().join("src")
}

#[test]
fn no_written_file_is_over_700_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut all = vec![root.join("README.md")];
    let exts = ["rs", "md", "toml", "py", "sh", "yaml", "h", "c"];
    for dir in [
        "src",
        "tests",
        "benches",
        "examples",
        "capi",
        "python",
        "scripts",
        "farm",
        "fuzz",
        "pipelines",
        "docs",
    ] {
        written_files(&root.join(dir), &exts, &mut all);
    }
    assert!(
        all.len() > 200,
        "only {} files found: the walk is off",
        all.len()
    );
    let long: Vec<String> = all
        .iter()
        .map(|f| (f, fs::read_to_string(f).unwrap().lines().count()))
        .filter(|(_, n)| *n > MAX_LINES)
        .map(|(f, n)| format!("{} ({n} lines)", f.display()))
        .collect();
    assert!(long.is_empty(), "over {MAX_LINES} lines: {long:#?}");
}

/// The import circles of the crate whose root is `dir/root`, each named by its files.
fn named_circles(dir: &Path, root: &str) -> Vec<String> {
    circles(&import_graph(dir, root))
        .iter()
        .map(|group| {
            group
                .iter()
                .map(|f| f.strip_prefix(dir).unwrap().display().to_string())
                .collect::<Vec<_>>()
                .join(" ↔ ")
        })
        .collect()
}

#[test]
fn no_files_import_each_other_in_a_circle() {
    let named = named_circles(&src(), "lib.rs");
    assert!(named.is_empty(), "import circles: {named:#?}");
}

#[test]
fn no_test_files_import_each_other_in_a_circle() {
    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/it");
    let named = named_circles(&tests, "main.rs");
    assert!(named.is_empty(), "import circles in tests/it: {named:#?}");
}

/// The checker itself finds a circle, through `use` trees, `super::` and inline paths, and ignores
/// paths in comments and strings.
#[test]
fn the_circle_finder_sees_the_three_ways_of_naming_a_file() {
    let dir = std::env::temp_dir().join(format!("gsid-layout-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(dir.join("a")).unwrap();
    let write = |p: &str, t: &str| fs::write(dir.join(p), t).unwrap();
    write("lib.rs", "pub mod a;\npub mod b;\npub mod c;\n");
    write("a/mod.rs", "mod x;\nmod y;\npub use x::X;\n");
    write("a/x.rs", "use super::{y::{self, Y}};\npub struct X;\n");
    write("a/y.rs", "pub struct Y;\nfn f() { let _ = super::x::X; }\n");
    write(
        "b.rs",
        "// crate::c::C\nfn g() { let _ = \"crate::c::C\"; let _ = 'c'; }\n",
    );
    write(
        "c.rs",
        "pub struct C;\nfn h() { crate::b::g(); }\n#[cfg(test)]\nmod tests { use super::*; }\n",
    );
    let found = circles(&import_graph(&dir, "lib.rs"));
    let _ = fs::remove_dir_all(&dir);
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!(
        found[0],
        vec![dir.join("a/x.rs"), dir.join("a/y.rs")],
        "{found:?}"
    );
}
