//! The docs hold together: every measurement the code, the pipelines or the docs cite as
//! `docs/RESULTS.md "Title"` is a section of one of the subject files under `docs/results/`, the
//! index in `docs/RESULTS.md` lists every section of every subject file and each of its links leads
//! to a heading, and every relative link in the Markdown files leads to a file.

use std::collections::BTreeSet;
use std::fs;
use std::path::PathBuf;

#[path = "shared/files.rs"]
mod files;
use files::written_files;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn flattened(text: &str, ext: &str) -> String {
    let markers: &[&str] = match ext {
        "rs" => &["//!", "///", "//"],
        "toml" | "py" | "sh" | "yaml" => &["#"],
        _ => &[],
    };
    let lines = text.lines().map(|line| {
        let line = line.trim();
        markers
            .iter()
            .find_map(|m| line.strip_prefix(m))
            .unwrap_or(line)
            .trim()
    });
    lines.collect::<Vec<_>>().join(" ")
}

/// The titles quoted right after each `RESULTS.md` in `flat` (`docs/RESULTS.md "Speed"`,
/// `docs/RESULTS.md, "Speed"`, `docs/RESULTS.md ("Speed"`), whitespace collapsed, cut at an
/// ellipsis (a title quoted by its start) and without a trailing full stop.
fn cited_titles(flat: &str) -> Vec<String> {
    let mut out = Vec::new();
    for (at, _) in flat.match_indices("RESULTS.md") {
        let rest = flat[at + "RESULTS.md".len()..].trim_start_matches([',', ':', ' ', '(']);
        let Some(open) = rest.chars().next().filter(|c| *c == '"' || *c == '“') else {
            continue;
        };
        let body = &rest[open.len_utf8()..];
        let Some(end) = body.find(['"', '”']) else {
            continue;
        };
        let title = body[..end].split('…').next().unwrap();
        let title = title.split_whitespace().collect::<Vec<_>>().join(" ");
        out.push(title.trim_end_matches(['.', ' ']).to_string());
    }
    out
}

/// Every `##` and `###` heading of the subject files under `docs/results/`, by file name.
fn result_headings() -> Vec<(String, String)> {
    let mut files = Vec::new();
    written_files(&root().join("docs/results"), &["md"], &mut files);
    assert!(!files.is_empty(), "no subject files under docs/results");
    let mut out = Vec::new();
    for file in files {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        for line in fs::read_to_string(&file).unwrap().lines() {
            if let Some(t) = line.strip_prefix("## ").or(line.strip_prefix("### ")) {
                out.push((name.clone(), t.to_string()));
            }
        }
    }
    out
}

/// GitHub's anchor for a heading: lower case, spaces to hyphens, every character that is not a
/// letter, a digit, a hyphen or an underscore dropped.
fn anchor(heading: &str) -> String {
    heading
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

#[test]
fn every_cited_measurement_is_a_section_of_the_results() {
    let titles: Vec<String> = result_headings().into_iter().map(|(_, t)| t).collect();
    let exts = ["rs", "md", "toml", "py", "sh", "yaml"];
    let mut files = Vec::new();
    for dir in [
        "src",
        "tests",
        "benches",
        "pipelines",
        "scripts",
        "docs",
        "python",
        "farm",
        "capi",
        "examples",
    ] {
        written_files(&root().join(dir), &exts, &mut files);
    }
    files.push(root().join("README.md"));
    // This file quotes examples of citations, not citations.
    files.retain(|f| !f.ends_with("tests/docs.rs"));
    let mut cited = 0;
    let mut missing = Vec::new();
    for file in files {
        let ext = file.extension().unwrap().to_string_lossy().into_owned();
        let text = fs::read_to_string(&file).unwrap();
        for title in cited_titles(&flattened(&text, &ext)) {
            cited += 1;
            if !titles.iter().any(|t| t.starts_with(&title)) {
                missing.push(format!("{}: \"{title}\"", file.display()));
            }
        }
    }
    assert!(
        cited > 50,
        "only {cited} citations found: the reader is off"
    );
    assert!(missing.is_empty(), "no such section: {missing:#?}");
}

#[test]
fn a_citation_is_read_across_comment_lines_and_by_its_start() {
    let text = "// as measured (docs/RESULTS.md, \"The leak\n// test's level…\").\n";
    assert_eq!(
        cited_titles(&flattened(text, "rs")),
        ["The leak test's level"]
    );
    let toml = "# docs/RESULTS.md \"Speed\". And docs/RESULTS.md alone.\n";
    assert_eq!(cited_titles(&flattened(toml, "toml")), ["Speed"]);
}

#[test]
fn the_results_index_lists_every_section_and_each_link_leads_to_it() {
    let index = fs::read_to_string(root().join("docs/RESULTS.md")).unwrap();
    let mut linked = BTreeSet::new();
    for (at, _) in index.match_indices("](results/") {
        let target = &index[at + 2..];
        let target = &target[..target.find(')').unwrap()];
        linked.insert(target.to_string());
    }
    let headings = result_headings();
    let mut unlisted = Vec::new();
    for (file, heading) in &headings {
        let link = format!("results/{file}#{}", anchor(heading));
        if !linked.remove(&link) {
            unlisted.push(link);
        }
    }
    let files: BTreeSet<String> = headings
        .iter()
        .map(|(f, _)| format!("results/{f}"))
        .collect();
    linked.retain(|l| !files.contains(l));
    assert!(
        unlisted.is_empty(),
        "sections the index misses: {unlisted:#?}"
    );
    assert!(linked.is_empty(), "index links to no heading: {linked:#?}");
}

#[test]
fn every_relative_link_in_the_docs_leads_to_a_file() {
    let mut files = vec![root().join("README.md")];
    for dir in [
        "docs", "python", "farm", "fuzz", "capi", "benches", "scripts",
    ] {
        written_files(&root().join(dir), &["md"], &mut files);
    }
    let mut broken = Vec::new();
    for file in &files {
        let text = fs::read_to_string(file).unwrap();
        for (at, _) in text.match_indices("](") {
            let rest = &text[at + 2..];
            let Some(end) = rest.find(')') else { continue };
            let target = rest[..end].split('#').next().unwrap();
            if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            if !file.parent().unwrap().join(target).exists() {
                broken.push(format!("{}: {target}", file.display()));
            }
        }
    }
    assert!(broken.is_empty(), "links to nothing: {broken:#?}");
}
