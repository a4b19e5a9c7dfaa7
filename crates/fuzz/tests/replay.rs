//! The committed fuzz corpus and every minimised crash, replayed on stable: each input must be
//! read without a panic, and refused (if refused) in one line naming the file. CI checks them
//! this way without a nightly toolchain. Also: the seeds are valid files of their readers, so
//! that fuzzing starts deep inside each format.

use std::path::{Path, PathBuf};
use std::time::Instant;

use timesift_fuzz::campaign::{finding, read_inputs};
use timesift_fuzz::{Target, Verdict};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The address space the replay runs in: an input that makes a reader allocate what its few
/// kilobytes do not justify aborts there, as it would on a small machine, instead of passing
/// on this one's memory.
const REPLAY_ADDRESS_SPACE: u64 = 512 << 20;

/// Set in the child that replays under the limit.
const CHILD: &str = "TIMESIFT_FUZZ_REPLAY_CHILD";

#[test]
fn committed_corpus_and_regressions_replay_without_a_finding() {
    if std::env::var_os(CHILD).is_some() {
        return replay_all();
    }
    // This test again, in a child process under the address-space limit.
    let mut child = std::process::Command::new(std::env::current_exe().unwrap());
    child
        .args([
            "--exact",
            "committed_corpus_and_regressions_replay_without_a_finding",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD, "1");
    timesift_fuzz::limit_address_space(&mut child, REPLAY_ADDRESS_SPACE);
    let output = child.output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    println!("{text}");
    assert!(
        output.status.success(),
        "the replay under {REPLAY_ADDRESS_SPACE} bytes of address space failed ({}):\n{text}",
        output.status
    );
    assert!(text.contains("inputs replayed"), "{text}");
}

fn replay_all() {
    let fuzz = workspace().join("fuzz");
    let mut failures = Vec::new();
    let started = Instant::now();
    let mut replayed = 0;
    for target in Target::ALL {
        let corpus = read_inputs(&fuzz.join("corpus").join(target.name())).unwrap();
        // A target whose corpus went missing would pass vacuously.
        assert!(
            !corpus.is_empty(),
            "fuzz/corpus/{target} is empty; `cargo xtask fuzz --seed` writes its seeds"
        );
        let regressions = read_inputs(&fuzz.join("regressions").join(target.name())).unwrap();
        for (path, bytes) in corpus.iter().chain(&regressions) {
            replayed += 1;
            if let Some(f) = finding(target, bytes) {
                failures.push(format!("{}: {f}", path.display()));
            }
        }
    }
    println!(
        "{replayed} inputs replayed in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The seeds of `target`, or `None` (and why, printed) without `../shared/data`.
fn seeds_of(target: Target) -> Option<Vec<timesift_fuzz::seeds::Seed>> {
    let root = workspace();
    let shared = root.join("../shared/data");
    if !shared.is_dir() {
        println!("skipped: {} is missing", shared.display());
        return None;
    }
    let scratch = tempfile::tempdir().unwrap();
    Some(timesift_fuzz::seeds::seeds(target, &root, &shared, scratch.path()).unwrap())
}

#[test]
fn every_seed_is_accepted_by_its_reader() {
    let mut wrong = Vec::new();
    for target in Target::ALL {
        let Some(seeds) = seeds_of(target) else {
            return;
        };
        assert!(!seeds.is_empty(), "{target} has no seed");
        for (name, bytes) in seeds {
            let verdict = timesift_fuzz::run(target, &bytes);
            // A seed made for another project's files is read, and refused over those files.
            let expected = if name.ends_with(timesift_fuzz::seeds::ELSEWHERE) {
                matches!(verdict, Ok(Verdict::Refused(_)))
            } else {
                verdict == Ok(Verdict::Accepted)
            };
            if !expected {
                wrong.push(format!("seed {name} of {target}: {verdict:?}"));
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn a_truncated_seed_is_refused_in_one_line_naming_the_file() {
    // Binary formats whose every proper prefix is invalid.
    for target in [
        Target::FeaturesBin,
        Target::MatchesBin,
        Target::Libmv,
        Target::Exr,
    ] {
        let Some(seeds) = seeds_of(target) else {
            return;
        };
        let (_, bytes) = &seeds[0];
        for len in [0, 1, bytes.len() / 2, bytes.len() - 1] {
            match timesift_fuzz::run(target, &bytes[..len]) {
                Ok(Verdict::Refused(message)) => assert!(!message.is_empty()),
                other => panic!("{target} cut at {len}: {other:?}"),
            }
        }
    }
}
