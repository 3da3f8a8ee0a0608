//! Every command example runs: each line of README.md's ```sh blocks that starts with `gsid `, and
//! each `gsid …` line of every `--help`, from a working folder that sees the bundled `fixtures/`
//! and `pipelines/` (as the repository root does), with the binary as `gsid`. An example that
//! stops working fails here, naming it.

use std::path::Path;

use crate::common::{gsid, gsid_command, stderr};

/// Splits a shell line into words: single and double quotes, backslash escapes, and a `#` that
/// starts a word begins a comment. Enough for the examples, which use no variables or pipes.
fn shell_words(line: &str) -> Vec<String> {
    let (mut words, mut word, mut in_word) = (Vec::new(), String::new(), false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '#' if !in_word => break,
            ' ' | '\t' => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            '\'' => {
                in_word = true;
                for q in chars.by_ref() {
                    if q == '\'' {
                        break;
                    }
                    word.push(q);
                }
            }
            '"' => {
                in_word = true;
                while let Some(q) = chars.next() {
                    match q {
                        '"' => break,
                        '\\' => word.extend(chars.next()),
                        _ => word.push(q),
                    }
                }
            }
            '\\' => {
                in_word = true;
                word.extend(chars.next());
            }
            _ => {
                in_word = true;
                word.push(c);
            }
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

/// The `gsid …` commands of a Markdown text's ```sh blocks, continuation lines joined.
fn readme_commands(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut in_sh = false;
    let mut pending = String::new();
    for line in text.lines() {
        let trimmed = line.trim();
        if trimmed.starts_with("```") {
            in_sh = trimmed == "```sh";
            continue;
        }
        if !in_sh {
            continue;
        }
        if let Some(head) = trimmed.strip_suffix('\\') {
            pending.push_str(head.trim_end());
            pending.push(' ');
            continue;
        }
        let full = format!("{pending}{trimmed}");
        pending.clear();
        if full.starts_with("gsid ") {
            out.push(full);
        }
    }
    out
}

/// The `gsid …` lines of every help text: the top level's and each subcommand's.
fn help_commands() -> Vec<String> {
    let mut out = Vec::new();
    for sub in [
        "",
        "denoise",
        "eval",
        "pipelines",
        "render",
        "ablate",
        "sweep",
    ] {
        let args: Vec<&str> = [sub, "--help"]
            .into_iter()
            .filter(|a| !a.is_empty())
            .collect();
        let run = gsid(&args);
        assert_eq!(run.status.code(), Some(0), "gsid {sub} --help");
        let text = String::from_utf8_lossy(&run.stdout).into_owned();
        let found: Vec<String> = text
            .lines()
            .map(str::trim)
            .filter(|l| l.starts_with("gsid "))
            .map(String::from)
            .collect();
        assert!(!found.is_empty(), "gsid {sub} --help has no example");
        out.extend(found);
    }
    out
}

/// A working folder where `fixtures/` and `pipelines/` are the repository's (read through links,
/// so an example that wrote into them would be caught by gsid's own input checks, not hidden).
fn workdir() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for name in ["fixtures", "pipelines"] {
        std::os::unix::fs::symlink(root.join(name), dir.path().join(name)).unwrap();
    }
    dir
}

/// Runs each command in one working folder, in order (an example may read what an earlier one
/// wrote, as a reader following the README would), and lists every one that failed.
fn run_all(commands: &[String]) {
    let dir = workdir();
    let mut failed = Vec::new();
    for line in commands {
        let words = shell_words(line);
        assert_eq!(words[0], "gsid", "{line}");
        let run = gsid_command()
            .args(&words[1..])
            .current_dir(dir.path())
            .output()
            .expect("run gsid");
        if run.status.code() != Some(0) {
            failed.push(format!(
                "{line}\n    exit {:?}: {}",
                run.status.code(),
                stderr(&run).trim()
            ));
        }
    }
    assert!(
        failed.is_empty(),
        "{} of {} examples failed:\n{}",
        failed.len(),
        commands.len(),
        failed.join("\n")
    );
}

#[test]
fn the_shell_splitter_reads_quotes_escapes_and_comments() {
    assert_eq!(
        shell_words("gsid denoise 'a/f.####.exr' -o \"o b.exr\" x\\ y   # note"),
        ["gsid", "denoise", "a/f.####.exr", "-o", "o b.exr", "x y"]
    );
    let md = "text\n```sh\ngsid a \\\n    b\ncargo test\n```\n```text\ngsid c\n```\n";
    assert_eq!(readme_commands(md), ["gsid a b"]);
}

#[test]
fn every_readme_example_runs() {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).unwrap();
    let commands = readme_commands(&readme);
    assert!(
        commands.len() >= 10,
        "the README's sh blocks hold {} gsid commands",
        commands.len()
    );
    run_all(&commands);
}

#[test]
fn every_help_example_runs() {
    run_all(&help_commands());
}
