//! Faults injected into whole runs (`timesift-io`'s `fault-injection` feature, armed by
//! `TIMESIFT_FAULT=<op>:<n>`): the n-th write, rename or fsync of a `timesift run` fails. The run
//! must stop with one line naming the file, leave every product it had written complete and
//! no temporary file behind, and the next run must complete to the products of a run that met
//! no fault. Killed at a seeded random moment inside each stage in turn (`kill:<n>:<path>`),
//! the runs resume to those products too.

use std::path::Path;
use std::process::Command;

use crate::common::{assert_same_products, complete, copy_tree, files, small_landslide, timesift};

/// The faults tried, one of each operation in a different stage: the first write of a file
/// whose path holds the marker, and so on, counted in the log of a run that met no fault
/// (`TIMESIFT_FAULT_LOG`), so that each lands where it is meant to whatever the counts.
const FAULTS: [(&str, &str); 3] = [
    ("write", "/work/matches/"),
    ("rename", "/work/dense/"),
    ("fsync", "/out/change/"),
];

/// The log's operations: (kind, count of its kind, count of all, file).
fn operations(log: &str) -> Vec<(String, u64, u64, String)> {
    log.lines()
        .filter_map(|line| {
            let mut words = line.splitn(4, ' ');
            Some((
                words.next()?.to_lowercase(),
                words.next()?.parse().ok()?,
                words.next()?.parse().ok()?,
                words.next()?.to_string(),
            ))
        })
        .collect()
}

/// `op:n` for the first `op` on a path holding `marker` in the log.
fn fault_in(log: &str, op: &str, marker: &str) -> String {
    operations(log)
        .into_iter()
        .find(|(o, _, _, path)| o == op && path.contains(marker))
        .map(|(_, n, _, _)| format!("{op}:{n}"))
        .unwrap_or_else(|| panic!("no {op} under {marker} in a run"))
}

fn run_with_fault(dir: &Path, fault: &str) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(["run", dir.to_str().expect("utf-8"), "--quiet"])
        .env("TIMESIFT_FAULT", fault)
        .output()
        .expect("the binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_failed_write_rename_or_fsync_loses_nothing_and_the_next_run_completes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (fresh, whole) = (tmp.path().join("fresh"), tmp.path().join("whole"));
    small_landslide(&fresh);
    copy_tree(&fresh, &whole);
    let log_path = tmp.path().join("operations.log");
    let out = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(["run", whole.to_str().expect("utf-8"), "--quiet"])
        .env("TIMESIFT_FAULT_LOG", &log_path)
        .output()
        .expect("the binary runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let log = std::fs::read_to_string(&log_path).expect("the operations' log");
    let mut folders = std::collections::BTreeMap::<String, usize>::new();
    for (_, _, _, path) in operations(&log) {
        let relative = path
            .strip_prefix(&*whole.to_string_lossy())
            .unwrap_or(&path);
        let folder: Vec<&str> = relative
            .split('/')
            .filter(|s| !s.is_empty())
            .take(2)
            .collect();
        *folders.entry(folder.join("/")).or_default() += 1;
    }
    println!(
        "a run: {} writes, renames and fsyncs: {folders:?}",
        log.lines().count()
    );
    for (op, marker) in FAULTS {
        let fault = fault_in(&log, op, marker);
        let fault = fault.as_str();
        let dir = tmp.path().join(fault.replace(':', "-"));
        copy_tree(&fresh, &dir);
        let (ok, err) = run_with_fault(&dir, fault);
        assert!(!ok, "{fault}: the run met no such operation and succeeded");
        let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{fault}: not one line:\n{err}");
        assert!(
            lines[0].contains("injected") && lines[0].contains(&*dir.to_string_lossy()),
            "{fault}: {}",
            lines[0]
        );
        // What the failed run left: complete products, no temporary file anywhere.
        for f in files(&dir.join("out")) {
            complete(&dir.join("out").join(&f)).unwrap_or_else(|e| panic!("{fault}: {e}"));
        }
        let temporaries: Vec<_> = files(&dir)
            .into_iter()
            .filter(|f| f.to_string_lossy().contains(".tmp-"))
            .collect();
        assert!(temporaries.is_empty(), "{fault}: {temporaries:?}");
        let (ok, _, err) = timesift(&["run", dir.to_str().expect("utf-8"), "--quiet"]);
        assert!(ok, "{fault}: the next run failed: {err}");
        assert_same_products(&whole, &dir);
        println!("{fault}: {}", lines[0]);
    }
    killed_inside_every_stage(&fresh, &whole, &log, tmp.path());
}

/// The stages in their order, each by a text of the paths it writes.
const STAGE_PATHS: [(&str, &str); 8] = [
    ("features", "/work/features/"),
    ("match", "/work/matches/"),
    ("align", "colmap"),
    ("dense", "/work/dense/"),
    ("dem", "/dem"),
    ("ortho", "/ortho"),
    ("change", "/out/change/"),
    ("report", "/out/report.html"),
];

/// One project killed inside each stage in turn, at a seeded random one of the stage's writes,
/// renames and fsyncs (before it is done: a temporary left, a rename not made), each run
/// resuming the last: every product present at a kill is complete, and the run after the last
/// kill ends with the products of a run that met none.
fn killed_inside_every_stage(fresh: &Path, whole: &Path, log: &str, tmp: &Path) {
    let dir = tmp.join("killed");
    copy_tree(fresh, &dir);
    let ops = operations(log);
    let mut rng = timesift_core::SeededRng::new(20_261_129);
    for (stage, marker) in STAGE_PATHS {
        let count = ops.iter().filter(|(_, _, _, p)| p.contains(marker)).count();
        assert!(
            count > 0,
            "{stage}: no operation on a path holding {marker}"
        );
        let n = 1 + rng.below(count);
        let (ok, err) = run_with_fault(&dir, &format!("kill:{n}:{marker}"));
        assert!(
            !ok,
            "{stage}: not killed at its operation {n} of {count}: {err}"
        );
        for f in files(&dir.join("out")) {
            if !f.to_string_lossy().contains(".tmp-") {
                complete(&dir.join("out").join(&f))
                    .unwrap_or_else(|e| panic!("killed in {stage}: {e}"));
            }
        }
        println!("killed in {stage} at its operation {n} of {count}");
    }
    let (ok, _, err) = timesift(&["run", dir.to_str().expect("utf-8"), "--quiet"]);
    assert!(ok, "the run after the kills failed: {err}");
    assert_same_products(whole, &dir);
}

/// Damages a file the way a failing disk does: a digit of a JSON record changed (it still
/// parses), or a byte in the middle of a binary file flipped; with `truncate`, cuts the file to
/// two thirds instead.
fn damage(path: &Path, truncate: bool) {
    let mut bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    if truncate {
        bytes.truncate(bytes.len() * 2 / 3);
    } else if path.extension().is_some_and(|e| e == "json") {
        let at = bytes
            .iter()
            .rposition(|b| (b'1'..=b'8').contains(b))
            .unwrap_or_else(|| panic!("{}: no digit to change", path.display()));
        bytes[at] += 1;
    } else {
        let at = bytes.len() / 2;
        bytes[at] ^= 0x04;
    }
    std::fs::write(path, bytes).expect("write");
}

/// One file of each kind the stages cache under `work/`: features, matches, depth maps of a
/// pass and filtered, and the records of what each stage's results were made from; with
/// `stage_records`, also the records a whole stage's cache hangs on (`settings.json` of the
/// features and the dense maps, `features/images.json`): damaged, nothing says what the cache
/// was made from, and the whole stage is redone.
fn cached_files(dir: &Path, stage_records: bool) -> Vec<std::path::PathBuf> {
    let work = dir.join("work");
    let all = files(&work);
    let first = |pattern: &dyn Fn(&str) -> bool| {
        all.iter()
            .map(|f| f.to_string_lossy().into_owned())
            .find(|f| pattern(f))
            .map(|f| work.join(f))
            .unwrap_or_else(|| panic!("no cached file of a kind under {}", work.display()))
    };
    let mut found = vec![
        first(&|f| f.starts_with("features/") && f.ends_with(".feat")),
        first(&|f| f.starts_with("matches/") && f.ends_with(".match")),
        first(&|f| f == "matches/pairs.json"),
        first(&|f| f == "matches/summary.json"),
        first(&|f| f == "align.json"),
        // The last pass's map: the one the fusion reads (an earlier pass's is read only to
        // make a later pass's again).
        {
            let last = all
                .iter()
                .filter_map(|f| {
                    f.to_str()?
                        .split("/pass")
                        .nth(1)?
                        .split('/')
                        .next()?
                        .parse::<usize>()
                        .ok()
                })
                .max()
                .expect("a pass");
            first(&|f| f.contains(&format!("/pass{last}/")) && f.ends_with(".exr"))
        },
        first(&|f| f.contains("/filtered/") && f.ends_with(".exr")),
        first(&|f| f.starts_with("dense/") && f.ends_with("/summary.json")),
        first(&|f| f.starts_with("dense/") && f.ends_with("/cloud.json")),
        first(&|f| f.starts_with("raster/") && f.ends_with(".dem.json")),
        first(&|f| f.starts_with("raster/") && f.ends_with(".ortho.json")),
        first(&|f| f.starts_with("change/") && f.ends_with(".json")),
    ];
    if stage_records {
        found.extend([
            first(&|f| f == "features/settings.json"),
            first(&|f| f == "features/images.json"),
            first(&|f| f.starts_with("dense/") && f.ends_with("/settings.json")),
        ]);
    }
    found
}

/// A file of `work/` is trusted only when it reads back as written.
fn reads_back(path: &Path) -> Result<(), String> {
    let bad = |e: String| format!("{}: {e}", path.display());
    match path.extension().and_then(|e| e.to_str()) {
        Some("feat") => timesift_matching::storage::read_features(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        Some("match") => timesift_matching::storage::read_matches(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        Some("exr") => timesift_io::exr::read_f32_channels(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
        _ => timesift::report::read_sealed_json::<serde_json::Value>(path)
            .map(|_| ())
            .map_err(|e| bad(e.to_string())),
    }
}

/// A flipped byte or a truncation in any cached file under `work/` is noticed: the unit it
/// belongs to is made again (its file reads back as written afterwards), and the products are
/// those of a run that met no damage.
#[test]
fn damaged_caches_are_recomputed_never_trusted() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("project");
    small_landslide(&dir);
    let (ok, _, err) = timesift(&["run", dir.to_str().expect("utf-8"), "--quiet"]);
    assert!(ok, "{err}");
    let reference = tmp.path().join("reference");
    copy_tree(&dir.join("out"), &reference.join("out"));
    // A flipped byte in one file of each unit's kind, then every cached file of each kind cut
    // short, the stages' own records too.
    for truncate in [false, true] {
        let damaged = cached_files(&dir, truncate);
        for f in &damaged {
            reads_back(f).unwrap_or_else(|e| panic!("before the damage: {e}"));
            damage(f, truncate);
            assert!(
                reads_back(f).is_err(),
                "{}: damage not noticed",
                f.display()
            );
        }
        let (ok, _, err) = timesift(&["run", dir.to_str().expect("utf-8")]);
        assert!(ok, "truncate {truncate}: {err}");
        let features = err
            .lines()
            .find(|l| l.starts_with("features"))
            .unwrap_or_else(|| panic!("no features line: {err}"));
        let expected = match truncate {
            false => "features of 1 images extracted (19 cached)",
            true => "features of 20 images extracted (0 cached)",
        };
        assert!(features.contains(expected), "{features}");
        for f in &damaged {
            if f.exists() {
                reads_back(f).unwrap_or_else(|e| panic!("truncate {truncate}: left damaged: {e}"));
            }
        }
        assert_same_products(&reference, &dir);
    }
}

/// `timesift run DIR --quiet` as a child whose files may grow to `bytes` at most
/// (`RLIMIT_FSIZE`, SIGXFSZ ignored so that the write fails with EFBIG instead of killing it):
/// a disk that fills up, as a process sees it. (success, standard error)
fn run_with_file_size_limit(dir: &Path, bytes: u64) -> (bool, String) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_timesift"));
    command.args(["run", dir.to_str().expect("utf-8"), "--quiet"]);
    crate::common::output_with_limit(&mut command, libc::RLIMIT_FSIZE, bytes)
}

/// The products under `out/` and their bytes.
fn snapshot(dir: &Path) -> std::collections::BTreeMap<std::path::PathBuf, Vec<u8>> {
    files(&dir.join("out"))
        .into_iter()
        .map(|f| {
            let bytes = std::fs::read(dir.join("out").join(&f)).expect("read");
            (f, bytes)
        })
        .collect()
}

/// What a failed run must leave: one error line naming a file of the project and saying why,
/// every product complete, no temporary file.
fn assert_failed_cleanly(dir: &Path, err: &str, why: &str) -> String {
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "not one line:\n{err}");
    assert!(
        lines[0].contains(&*dir.to_string_lossy()) && lines[0].contains(why),
        "{}",
        lines[0]
    );
    for f in files(&dir.join("out")) {
        complete(&dir.join("out").join(&f)).unwrap_or_else(|e| panic!("{e}"));
    }
    let temporaries: Vec<_> = files(dir)
        .into_iter()
        .filter(|f| f.to_string_lossy().contains(".tmp-"))
        .collect();
    assert!(temporaries.is_empty(), "{temporaries:?}");
    lines[0].to_string()
}

/// A tmpfs mounted for the test's life.
struct Mounted(std::path::PathBuf);

impl Drop for Mounted {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// The disk fills up while the dense clouds are made again (each file may grow to half the
/// smallest cloud): the run stops with one line naming the file, the earlier products are
/// untouched, and the next run, with room, completes. Then, where the test may mount a tmpfs
/// (root), the whole project on a 40 MB one: the run stops where the space ends, and completes
/// once the tmpfs is grown.
#[test]
fn a_full_disk_stops_the_run_in_one_line_and_the_next_run_completes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("project");
    small_landslide(&dir);
    let (ok, _, err) = timesift(&[
        "run",
        dir.to_str().expect("utf-8"),
        "--quiet",
        "--to",
        "dense",
    ]);
    assert!(ok, "{err}");
    let before = snapshot(&dir);
    let clouds: Vec<std::path::PathBuf> = before
        .keys()
        .filter(|f| f.extension().is_some_and(|e| e == "laz"))
        .cloned()
        .collect();
    assert!(!clouds.is_empty());
    for cloud in &clouds {
        std::fs::remove_file(dir.join("out").join(cloud)).expect("remove");
    }
    // Half the smallest cloud: the dense stage cannot write what it makes.
    let limit = clouds.iter().map(|c| before[c].len()).min().unwrap_or(0) as u64 / 2;
    let (ok, err) = run_with_file_size_limit(&dir, limit);
    assert!(!ok, "the run met no file over {limit} bytes");
    let line = assert_failed_cleanly(&dir, &err, "File too large");
    assert!(
        line.contains("/work/dense/") || line.contains("dense.laz"),
        "{line}"
    );
    println!("file size limit: {line}");
    let after = snapshot(&dir);
    for (f, bytes) in &after {
        assert_eq!(
            before.get(f),
            Some(bytes),
            "{}: changed by the failed run",
            f.display()
        );
    }
    let (ok, _, err) = timesift(&["run", dir.to_str().expect("utf-8"), "--quiet"]);
    assert!(ok, "the next run failed: {err}");
    for f in files(&dir.join("out")) {
        complete(&dir.join("out").join(&f)).unwrap_or_else(|e| panic!("{e}"));
    }

    // A real small file system, where this test may mount one.
    let disk = tmp.path().join("disk");
    std::fs::create_dir_all(&disk).expect("mkdir");
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=40m", "tmpfs"])
        .arg(&disk)
        .output();
    match mounted {
        Ok(out) if out.status.success() => {}
        Ok(out) => {
            println!(
                "no tmpfs part: mount failed ({}), the test is not root",
                String::from_utf8_lossy(&out.stderr).trim()
            );
            return;
        }
        Err(e) => {
            println!("no tmpfs part: no mount command ({e})");
            return;
        }
    }
    let _unmount = Mounted(disk.clone());
    let project = disk.join("project");
    small_landslide(&project);
    let (ok, _, err) = timesift(&["run", project.to_str().expect("utf-8"), "--quiet"]);
    assert!(!ok, "the project fitted in 40 MB");
    let line = assert_failed_cleanly(&project, &err, "No space left on device");
    println!("40 MB tmpfs: {line}");
    let grown = Command::new("mount")
        .args(["-o", "remount,size=400m"])
        .arg(&disk)
        .status()
        .expect("mount");
    assert!(grown.success(), "remount failed");
    let (ok, _, err) = timesift(&["run", project.to_str().expect("utf-8"), "--quiet"]);
    assert!(ok, "the next run, with room, failed: {err}");
    for f in files(&project.join("out")) {
        complete(&project.join("out").join(&f)).unwrap_or_else(|e| panic!("{e}"));
    }
}
