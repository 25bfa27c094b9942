//! The README's examples are tests, as RTIC's examples are: every ```` ```sh ```` block runs as
//! written, in order, with the `jdbb` under test first on PATH, in a temporary directory that
//! holds a link to the repository's `data/` (what the blocks read; they write `out/`); a
//! ```` ```text expected-output ```` block right after one is exactly what that block prints.
//! A block a test cannot run (the two top-level commands themselves, flashing a real board) is
//! marked ```` ```sh no-run ````; every such block must say why in a comment.
use std::path::{Path, PathBuf};
use std::process::Command;

/// One fenced block: the line its fence opens on, its info string, its text.
struct Block {
    line: usize,
    info: String,
    text: String,
}

fn blocks(readme: &str) -> Vec<Block> {
    let mut out = vec![];
    let mut open: Option<Block> = None;
    for (i, line) in readme.lines().enumerate() {
        if let Some(rest) = line.strip_prefix("```") {
            match open.take() {
                Some(b) => out.push(b),
                None => {
                    open = Some(Block {
                        line: i + 1,
                        info: rest.trim().to_string(),
                        text: String::new(),
                    })
                }
            }
        } else if let Some(b) = open.as_mut() {
            b.text.push_str(line);
            b.text.push('\n');
        }
    }
    assert!(open.is_none(), "a code block is not closed");
    out
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The documents whose blocks are run: the README, and the papers' reproductions moved out of it.
const DOCUMENTS: [&str; 2] = ["README.md", "docs/papers.md"];

#[test]
fn readme_blocks_are_well_formed() {
    for doc in DOCUMENTS {
        well_formed(doc);
    }
}

fn well_formed(doc: &str) {
    let readme = std::fs::read_to_string(root().join(doc)).unwrap();
    for b in blocks(&readme) {
        if !b.info.starts_with("sh") {
            continue;
        }
        for (k, l) in b.text.lines().enumerate() {
            let code = l.split(" #").next().unwrap_or("");
            assert!(
                !code.contains(" [-") && !code.contains("...") && !code.contains(" … "),
                "{doc}:{}: `{l}` has a placeholder or a bracketed option; a command in the README must run as pasted (options go in prose or tables)",
                b.line + 1 + k
            );
        }
        if b.info == "sh no-run" {
            assert!(
                b.text.contains('#'),
                "{doc}:{}: a `sh no-run` block must say in a comment why it cannot run in a test",
                b.line
            );
        } else {
            assert_eq!(
                b.info, "sh",
                "{doc}:{}: shell blocks are `sh` or `sh no-run`",
                b.line
            );
        }
    }
}

#[test]
fn readme_commands_run_as_written() {
    run_blocks("README.md");
}

#[test]
fn docs_papers_commands_run_as_written() {
    run_blocks("docs/papers.md");
}

/// Run every `sh` block of `doc` in order in a directory of its own, and compare each output shown.
fn run_blocks(doc: &str) {
    let root = root();
    let readme = std::fs::read_to_string(root.join(doc)).unwrap();
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_jdbb"));
    let path = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let all = blocks(&readme);
    // The blocks read `data/` and write `out/`: run them in a directory of their own, with the
    // repository's `data/` linked in, so a test run never writes into the working tree.
    let work = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(root.join("data"), work.path().join("data")).unwrap();
    let mut ran = 0;
    // `JDBB_README_BLESS=1`: write what each block prints today into its expected output instead
    // of failing, for a change whose new figures have been checked (review the diff).
    let bless = std::env::var_os("JDBB_README_BLESS").is_some();
    let mut blessed: Vec<(usize, String, String)> = vec![];
    for (k, b) in all.iter().enumerate() {
        if b.info != "sh" {
            continue;
        }
        let o = Command::new("bash")
            .args(["-euo", "pipefail", "-c", &b.text])
            .current_dir(work.path())
            .env("PATH", &path)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "{doc}:{}: this block failed ({}):\n{}\nstdout:\n{}\nstderr:\n{}",
            b.line,
            o.status,
            b.text,
            stdout,
            String::from_utf8_lossy(&o.stderr)
        );
        if let Some(next) = all.get(k + 1) {
            if next.info == "text expected-output" && bless && stdout != next.text {
                blessed.push((next.line, next.text.clone(), stdout.to_string()));
            } else if next.info == "text expected-output" {
                assert_eq!(
                    stdout, next.text,
                    "{doc}:{}: the output shown is not what the block above it prints today",
                    next.line
                );
            }
        }
        ran += 1;
    }
    assert!(ran >= 3, "only {ran} blocks of {doc} ran");
    if !blessed.is_empty() {
        // Replace each expected block (its lines after the fence) by what was printed.
        let mut lines: Vec<String> = readme.lines().map(str::to_string).collect();
        for (line, old, new) in blessed.iter().rev() {
            let n = old.lines().count();
            lines.splice(*line..*line + n, new.lines().map(str::to_string));
        }
        let mut text = lines.join("\n");
        text.push('\n');
        std::fs::write(root.join(doc), text).unwrap();
        let at: Vec<usize> = blessed.iter().map(|b| b.0).collect();
        panic!("{doc}: expected outputs at lines {at:?} rewritten (JDBB_README_BLESS); review the diff");
    }
}
