//! The README and `--help` agree, and its examples run: every `deltaz ...` line of the README
//! names a command whose `--help` lists each of its options; every line without placeholders
//! (IMAGE..., A.csv, MM, alternatives a|b) runs, in order, in one directory, with its optional
//! `[...]` parts left out.

use crate::cli::deltaz_in;

const README: &str = include_str!("../../../README.md");

/// The line without `# comment` and, with `optional` false, without its `[...]` parts.
fn words(line: &str, optional: bool) -> Vec<String> {
    let line = line.split(" # ").next().unwrap();
    let mut kept = String::new();
    let mut depth = 0;
    for c in line.chars() {
        match c {
            '[' => depth += 1,
            ']' => depth -= 1,
            _ if depth == 0 || optional => kept.push(c),
            _ => {}
        }
    }
    kept.split_whitespace().skip(1).map(str::to_owned).collect()
}

/// A placeholder: IMAGE..., MM, A.csv, A/analysis.json, or alternatives.
fn placeholder(word: &str) -> bool {
    let upper = |part: &str| {
        let stem = part.split('.').next().unwrap_or(part);
        !stem.is_empty() && stem.chars().all(|c| c.is_ascii_uppercase())
    };
    word.contains("...") || word == "|" || word.split('/').any(upper)
}

#[test]
fn readme_examples_agree_with_help_and_run() {
    let lines: Vec<&str> = README
        .lines()
        .map(str::trim)
        .filter(|l| l.starts_with("deltaz "))
        .collect();
    assert!(lines.len() >= 12, "{lines:?}");
    let dir = tempfile::tempdir().unwrap();
    let mut ran = 0;
    for line in &lines {
        let all = words(line, true);
        let path: Vec<&str> = all
            .iter()
            .map(String::as_str)
            .take_while(|w| {
                !w.starts_with('-') && w.chars().all(|c| c.is_ascii_lowercase() || c == '-')
            })
            .collect();
        let mut help_args = path.clone();
        help_args.push("--help");
        let help = deltaz_in(dir.path(), &help_args);
        let help = String::from_utf8_lossy(&help.stdout);
        for flag in all.iter().filter(|w| w.starts_with("--")) {
            let flag = flag.split('=').next().unwrap();
            assert!(
                [" ", "\n", "["]
                    .iter()
                    .any(|end| help.contains(&format!("{flag}{end}"))),
                "README: {line}\n`deltaz {}` does not list {flag}:\n{help}",
                help_args.join(" ")
            );
        }
        let run = words(line, false);
        if run.iter().any(|w| placeholder(w)) {
            continue;
        }
        let args: Vec<&str> = run.iter().map(String::as_str).collect();
        let out = deltaz_in(dir.path(), &args);
        assert!(
            out.status.success(),
            "README: {line}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        ran += 1;
    }
    assert!(ran >= 9, "only {ran} README examples ran");
    assert!(dir.path().join("camera.yml").exists() && dir.path().join("p1.obs.csv").exists());
}
