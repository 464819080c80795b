//! The documentation stays true to the tree: every relative link of README.md and docs/*.md
//! reaches a file (and, with `#anchor`, a heading of it), every option the command line's
//! `--help` lists is in docs/CLI.md, every livebake option docs/CLI.md names still exists, and
//! the benchmark tables are what `scripts/bench-tables` makes of the recorded bench JSON.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// README.md and every Markdown file of docs/.
fn doc_files() -> Vec<PathBuf> {
    let mut files = vec![root().join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .expect("docs/")
        .map(|e| e.expect("docs/ entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The lines of a Markdown text outside fenced code blocks, with inline code spans removed.
fn prose_lines(text: &str) -> Vec<String> {
    let mut fenced = false;
    let mut out = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if !fenced {
            // Odd-numbered pieces between backticks are code.
            out.push(line.split('`').step_by(2).collect::<String>());
        }
    }
    out
}

/// GitHub's anchor of a heading: lower case; letters, digits, `-` and `_` kept, spaces
/// become `-`, everything else is dropped.
fn slug(heading: &str) -> String {
    heading
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .flat_map(char::to_lowercase)
        .collect()
}

/// The anchors of a Markdown file's headings (a repeated heading gets `-1`, `-2`, …).
fn anchors(text: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        let Some(heading) = line.strip_prefix('#').map(|h| h.trim_start_matches('#')) else { continue };
        if fenced || !heading.starts_with(' ') {
            continue;
        }
        let base = slug(heading.trim());
        let mut anchor = base.clone();
        let mut n = 0;
        while !seen.insert(anchor.clone()) {
            n += 1;
            anchor = format!("{base}-{n}");
        }
    }
    seen
}

/// The targets of `[text](target)` and `![alt](target)` links in prose.
fn link_targets(text: &str) -> Vec<String> {
    let mut targets = Vec::new();
    for line in prose_lines(text) {
        let mut rest = line.as_str();
        while let Some(i) = rest.find("](") {
            let after = &rest[i + 2..];
            let Some(end) = after.find(')') else { break };
            targets.push(after[..end].trim().to_string());
            rest = &after[end..];
        }
    }
    targets
}

#[test]
fn every_relative_link_and_anchor_resolves() {
    let mut broken = Vec::new();
    let mut checked = 0;
    for file in doc_files() {
        let text = read(&file);
        for target in link_targets(&text) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            let (path, anchor) = target.split_once('#').unwrap_or((&target, ""));
            let dest = if path.is_empty() { file.clone() } else { file.parent().unwrap().join(path) };
            if !dest.exists() {
                broken.push(format!("{}: {target} (no file {})", file.display(), dest.display()));
                continue;
            }
            if !anchor.is_empty()
                && dest.extension().is_some_and(|e| e == "md")
                && !anchors(&read(&dest)).contains(anchor)
            {
                broken.push(format!("{}: {target} (no heading with anchor #{anchor})", file.display()));
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
    // The docs link to each other: finding none means the parser stopped seeing links.
    assert!(checked >= 10, "only {checked} relative links found in README.md and docs/");
}

fn livebake_help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_livebake")).args(args).arg("--help").output().expect("livebake runs");
    assert!(out.status.success(), "livebake {args:?} --help failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).expect("help is UTF-8")
}

/// The subcommands `livebake --help` lists (without `help`).
fn subcommands() -> Vec<String> {
    let help = livebake_help(&[]);
    let section = help.split("Commands:").nth(1).expect("`livebake --help` lists its commands");
    section
        .lines()
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next())
        .filter(|name| *name != "help")
        .map(str::to_string)
        .collect()
}

/// The long options (`--name`) a help text lists.
fn help_options(help: &str) -> BTreeSet<String> {
    help.lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let l = if l.starts_with('-') && !l.starts_with("--") { l.split_once(", ")?.1 } else { l };
            let name = l.strip_prefix("--")?;
            let name: String = name.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '-').collect();
            (!name.is_empty()).then(|| format!("--{name}"))
        })
        .collect()
}

/// The `--name` words of a text.
fn option_words(text: &str) -> BTreeSet<String> {
    let mut words = BTreeSet::new();
    let mut rest = text;
    while let Some(i) = rest.find("--") {
        let before = rest[..i].chars().last();
        let name: String = rest[i + 2..].chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '-').collect();
        if !before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '-')
            && name.chars().next().is_some_and(|c| c.is_ascii_lowercase())
        {
            words.insert(format!("--{}", name.trim_end_matches('-')));
        }
        rest = &rest[i + 2 + name.len()..];
    }
    words
}

/// Options docs/CLI.md names that belong to other programs: `scripts/bench-compare`'s
/// (`--runs`, `--instructions`; its `--out` is livebake's too), `scripts/bench-tables`' and
/// `cargo`'s.
const OTHER_PROGRAMS_OPTIONS: [&str; 9] =
    ["--runs", "--instructions", "--date", "--machine", "--note", "--check", "--release", "--locked", "--test"];

#[test]
fn cli_md_names_every_option_of_every_command_and_no_other() {
    let cli_md = read(&root().join("docs/CLI.md"));
    let documented = option_words(&cli_md);
    let commands = subcommands();
    assert!(commands.len() >= 6, "too few subcommands found: {commands:?}");
    let mut all = help_options(&livebake_help(&[]));
    let mut missing = Vec::new();
    for command in &commands {
        if !cli_md.contains(&format!("## `livebake {command}")) {
            missing.push(format!("a `## `livebake {command}`` section"));
        }
        let options = help_options(&livebake_help(&[command]));
        assert!(!options.is_empty(), "no options parsed from `livebake {command} --help`");
        for option in options {
            if !documented.contains(&option) {
                missing.push(format!("{command} {option}"));
            }
            all.insert(option);
        }
    }
    assert!(missing.is_empty(), "docs/CLI.md lacks:\n{}", missing.join("\n"));
    let stale: Vec<&String> =
        documented.iter().filter(|o| !all.contains(*o) && !OTHER_PROGRAMS_OPTIONS.contains(&o.as_str())).collect();
    assert!(stale.is_empty(), "docs/CLI.md names options no command has: {stale:?}");
}

#[test]
fn slugs_follow_github() {
    assert_eq!(slug("Hot reload"), "hot-reload");
    assert_eq!(slug("`livebake run`: the live runtime"), "livebake-run-the-live-runtime");
    assert_eq!(slug("Units and conventions (W/m²)"), "units-and-conventions-wm²");
    let a = anchors("# A\n## A\n```\n# not a heading\n```\n#nospace\n");
    assert_eq!(a, ["a", "a-1"].iter().map(|s| s.to_string()).collect());
}

/// docs/BENCHMARKS.md's tables and the README's headline table are what `scripts/bench-tables`
/// makes of the bench JSON and arguments BENCHMARKS.md records: regenerated, never retyped.
#[test]
fn benchmark_tables_are_made_from_the_recorded_bench_json() {
    let out = Command::new("python3")
        .arg(root().join("scripts/bench-tables"))
        .arg("--check")
        .output()
        .expect("python3 runs (scripts/test installs it)");
    assert!(
        out.status.success(),
        "scripts/bench-tables --check: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
