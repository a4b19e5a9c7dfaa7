//! The command lines the README and the guide show are tested: each `timesift …` and `cargo
//! xtask …` line of their shell blocks (```sh, ```console, ```bash) is parsed by the program it
//! names, so a renamed command or flag breaks this test, not the reader. With
//! `TIMESIFT_CHECK_ARGS` set, `timesift` and `xtask` parse their command line and stop.
//!
//! Lines of other programs (`cargo nextest`, `mdbook`, `gdalinfo`, …) are left alone, as are
//! `cargo run … --example` lines (an example's arguments are its own).

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The README and every page of the guide.
fn documents() -> Vec<PathBuf> {
    let guide = root().join("docs/guide/src");
    let pages = crate::common::files(&guide)
        .into_iter()
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .map(|p| guide.join(p));
    std::iter::once(root().join("README.md"))
        .chain(pages)
        .collect()
}

/// Which program a documented line runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Program {
    Timesift,
    Xtask,
}

/// A documented command: where it is, which program, its arguments.
#[derive(Debug)]
struct Documented {
    place: String,
    program: Program,
    args: Vec<String>,
}

/// Splits a shell line into words: quotes group, `#` starts a comment outside quotes, a
/// variable stays as written (parsing needs no file to exist).
fn words(line: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut quote: Option<char> = None;
    for c in line.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                in_word = true;
            }
            (None, '#') if !in_word => break,
            (None, c) if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            (None, c) => {
                word.push(c);
                in_word = true;
            }
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

/// `>`, `>>`, `2>`, `&>`, `<`, `|`: the command's arguments end there.
fn is_redirection(word: &str) -> bool {
    let word = word.trim_start_matches(['1', '2', '&']);
    word.starts_with('>') || word.starts_with('<') || word == "|"
}

/// The program and its arguments, when the words run timesift or xtask.
fn command_of(words: &[String]) -> Option<(Program, Vec<String>)> {
    let w: Vec<&str> = words.iter().map(String::as_str).collect();
    let after = |n: usize| words[n..].to_vec();
    match w.as_slice() {
        ["timesift", ..] => Some((Program::Timesift, after(1))),
        ["cargo", "xtask", ..] => Some((Program::Xtask, after(2))),
        ["cargo", "run", rest @ ..] => {
            if rest.contains(&"--example") {
                return None;
            }
            let dashes = rest.iter().position(|x| *x == "--")?;
            let options = &rest[..dashes];
            let program = match options.iter().position(|x| *x == "-p") {
                Some(i) if options.get(i + 1) == Some(&"xtask") => Program::Xtask,
                Some(i) if options.get(i + 1) == Some(&"timesift") => Program::Timesift,
                Some(_) => return None,
                None => Program::Timesift,
            };
            Some((program, after(2 + dashes + 1)))
        }
        _ => None,
    }
}

/// Every documented timesift and xtask command line.
fn documented_commands() -> Vec<Documented> {
    let mut found = Vec::new();
    for file in documents() {
        let text = std::fs::read_to_string(&file).expect("a documentation page");
        let name = file
            .strip_prefix(root())
            .unwrap_or(&file)
            .display()
            .to_string();
        let mut in_shell = false;
        let mut pending = String::new();
        let mut start = 0;
        for (i, line) in text.lines().enumerate() {
            let trimmed = line.trim_start();
            if let Some(info) = trimmed.strip_prefix("```") {
                in_shell = !in_shell && matches!(info.trim(), "sh" | "console" | "bash");
                continue;
            }
            if !in_shell {
                continue;
            }
            // A prompt (`$ `) marks a command among its output in a console block.
            let line = trimmed.strip_prefix("$ ").unwrap_or(trimmed);
            if pending.is_empty() {
                start = i + 1;
            }
            match line.strip_suffix('\\') {
                Some(head) => {
                    pending.push_str(head);
                    pending.push(' ');
                    continue;
                }
                None => pending.push_str(line),
            }
            let all = std::mem::take(&mut pending);
            // Commands chained with && are each a command.
            for part in all.split("&&") {
                let words = words(part);
                // Leading variable assignments go; a redirection or a pipe ends the command.
                let words: Vec<String> = words
                    .into_iter()
                    .skip_while(|w| w.contains('=') && !w.starts_with('-'))
                    .take_while(|w| !is_redirection(w))
                    .collect();
                if let Some((program, args)) = command_of(&words) {
                    found.push(Documented {
                        place: format!("{name}:{start}"),
                        program,
                        args,
                    });
                }
            }
        }
    }
    found
}

/// The xtask binary, built as `cargo xtask` builds it.
fn xtask_binary() -> PathBuf {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(cargo)
        .args(["build", "--quiet", "-p", "xtask"])
        .current_dir(root())
        .status()
        .expect("cargo runs");
    assert!(status.success(), "cargo build -p xtask failed");
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("target"));
    target.join("debug").join("xtask")
}

/// The documented commands the programs refuse, with what they said.
fn refused(commands: &[Documented]) -> Vec<String> {
    let needs_xtask = commands.iter().any(|c| c.program == Program::Xtask);
    let xtask = needs_xtask.then(xtask_binary);
    let mut refused = Vec::new();
    for command in commands {
        let binary = match command.program {
            Program::Timesift => PathBuf::from(env!("CARGO_BIN_EXE_timesift")),
            Program::Xtask => xtask.clone().expect("built above"),
        };
        let out = Command::new(&binary)
            .args(&command.args)
            .env("TIMESIFT_CHECK_ARGS", "1")
            .current_dir(root())
            .output()
            .expect("the program runs");
        if !out.status.success() {
            let said = String::from_utf8_lossy(&out.stderr);
            let first = said.lines().next().unwrap_or("").to_string();
            refused.push(format!(
                "{}: {:?} {}: {first}",
                command.place,
                command.program,
                command.args.join(" ")
            ));
        }
    }
    refused
}

#[test]
fn every_documented_command_line_parses() {
    let commands = documented_commands();
    let timesift = commands
        .iter()
        .filter(|c| c.program == Program::Timesift)
        .count();
    let xtask = commands.len() - timesift;
    // The README alone shows the demo, a quick start and developer commands.
    assert!(
        timesift >= 5 && xtask >= 3,
        "found {timesift} timesift and {xtask} xtask lines"
    );
    let refused = refused(&commands);
    assert!(
        refused.is_empty(),
        "documented commands that no longer parse:\n{}",
        refused.join("\n")
    );
    println!("{timesift} timesift and {xtask} cargo xtask command lines parse");
}

/// The check itself: a renamed flag and a renamed command are refused, with the place named.
#[test]
fn a_renamed_flag_is_caught() {
    let command = |args: &[&str]| Documented {
        place: "README.md:1".into(),
        program: Program::Timesift,
        args: args.iter().map(|s| s.to_string()).collect(),
    };
    let good = command(&["run", "/tmp/p", "--from", "dense"]);
    let renamed_flag = command(&["run", "/tmp/p", "--start", "dense"]);
    let renamed_command = command(&["execute", "/tmp/p"]);
    let refused = refused(&[good, renamed_flag, renamed_command]);
    assert_eq!(refused.len(), 2, "{refused:?}");
    assert!(refused[0].starts_with("README.md:1") && refused[0].contains("--start"));
    assert!(refused[1].contains("execute"));
}

#[test]
fn shell_lines_are_split_as_a_shell_would() {
    assert_eq!(
        words("timesift run 'my project' --to dense   # a comment"),
        ["timesift", "run", "my project", "--to", "dense"]
    );
    let w = words("cargo run --release -p xtask -- synth archival --out /tmp/a");
    assert_eq!(
        command_of(&w),
        Some((
            Program::Xtask,
            vec![
                "synth".into(),
                "archival".into(),
                "--out".into(),
                "/tmp/a".into()
            ]
        ))
    );
    let w = words("cargo run --release -p timesift-dense --example plane_timing");
    assert_eq!(command_of(&w), None);
    assert!(is_redirection(">") && is_redirection("2>/dev/null") && is_redirection("|"));
    assert!(!is_redirection("--out") && !is_redirection("1,2,3"));
    let w = words("cargo run --release -- demo /tmp/d");
    assert_eq!(
        command_of(&w),
        Some((Program::Timesift, vec!["demo".into(), "/tmp/d".into()]))
    );
}
