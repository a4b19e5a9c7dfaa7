//! Units of work and the cluster executor on a rendered three-epoch project:
//! - every unit of the plan run alone with `timesift task`, each step's units in reverse order
//!   (the orthomosaics made in parts of rows of tiles, merged per epoch) and one of them killed
//!   with SIGKILL while it ran, gives the local run's products;
//! - two `timesift run` on one project: the second is refused naming the first, and after the
//!   first is killed a new one starts without any cleanup;
//! - `--executor slurm` on a real one-node Slurm (`cargo xtask slurm-up`; skipped with the
//!   reason where none answers): a running task cancelled with `scancel` shows as the only
//!   missing unit of its step, a second submission runs exactly what is missing (and is refused
//!   while Slurm still holds the first's tasks), and the products equal the local run's.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{comparable_json, copy_tree, files, quick_dense_level_4, timesift};
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

/// Three epochs of `landslide`, eight images each, dense at level 4 with the quick settings,
/// and a fine split so that every parallel step has several units.
fn project(dir: &Path) {
    let mut spec = build("landslide", Scale::Small, 3).expect("scene");
    spec.epochs.truncate(3);
    spec.keep_first_images(8);
    write_scene(&spec, dir, &WriteOptions::default()).expect("write");
    quick_dense_level_4(dir);
    let toml = dir.join("project.toml");
    let text = std::fs::read_to_string(&toml).expect("project.toml")
        + "\n[cluster]\nimages_per_task = 5\npairs_per_task = 40\nviews_per_task = 3\n\
           ortho_megapixels_per_task = 0.05\n";
    std::fs::write(&toml, text).expect("project.toml");
}

/// Every product of `b` equals `a`'s: the same files; cameras.json, clouds, rasters and
/// images byte for byte; JSON reports but for times and paths (report.html shows times).
fn assert_same_products(a: &Path, b: &Path) {
    let (fa, fb) = (files(&a.join("out")), files(&b.join("out")));
    assert_eq!(fa, fb, "different sets of products");
    assert!(fa.iter().any(|f| f.ends_with("dense.laz")), "{fa:?}");
    let mut differing = Vec::new();
    for f in &fa {
        let (pa, pb) = (a.join("out").join(f), b.join("out").join(f));
        let same = match f.extension().and_then(|e| e.to_str()) {
            Some("html") => continue,
            Some("json") => {
                comparable_json(&std::fs::read_to_string(&pa).expect("read"), a)
                    == comparable_json(&std::fs::read_to_string(&pb).expect("read"), b)
            }
            _ => std::fs::read(&pa).expect("read") == std::fs::read(&pb).expect("read"),
        };
        if !same {
            differing.push(f.clone());
        }
    }
    assert!(differing.is_empty(), "products differ: {differing:?}");
}

fn run_local(dir: &Path) {
    let (ok, _, err) = timesift(&["run", dir.to_str().expect("utf-8"), "--quiet"]);
    assert!(ok, "{err}");
}

/// The steps of the dry-run plan with their units.
fn plan(dir: &Path) -> Vec<(String, usize)> {
    let (ok, out, err) = timesift(&[
        "run",
        dir.to_str().expect("utf-8"),
        "--executor",
        "slurm",
        "--dry-run",
    ]);
    assert!(ok, "{err}");
    out.lines()
        .skip(1)
        .filter_map(|l| {
            let mut words = l.split_whitespace();
            let step = words.next().filter(|w| *w != "planned" && *w != "note:")?;
            let units = words.next()?.parse().ok()?;
            Some((step.to_string(), units))
        })
        .collect()
}

/// `timesift status`, in the plan's order: step, (units, complete, running, queued, failed,
/// missing).
fn status(dir: &Path, env: &[(&str, &str)]) -> Vec<(String, [usize; 6])> {
    let out = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(["status", dir.to_str().expect("utf-8")])
        .envs(env.iter().copied())
        .output()
        .expect("status");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .skip(1)
        .filter_map(|l| {
            let words: Vec<&str> = l.split_whitespace().collect();
            let n: Vec<usize> = words
                .get(1..7)?
                .iter()
                .map(|w| w.parse().ok())
                .collect::<Option<_>>()?;
            Some((words[0].to_string(), [n[0], n[1], n[2], n[3], n[4], n[5]]))
        })
        .collect()
}

fn task(dir: &Path, step: &str, i: usize, n: usize) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_timesift"));
    cmd.args([
        "task",
        step,
        dir.to_str().expect("utf-8"),
        "--part",
        &format!("{i}/{n}"),
    ]);
    cmd
}

#[test]
fn units_run_alone_in_any_order_and_after_a_kill_make_the_local_runs_products() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (local, units) = (tmp.path().join("local"), tmp.path().join("units"));
    project(&local);
    copy_tree(&local, &units);
    run_local(&local);

    let steps = plan(&units);
    for expected in ["features", "match", "dense-pass-0", "dense-fuse", "ortho"] {
        let (_, n) = steps.iter().find(|(s, _)| s == expected).expect(expected);
        assert!(*n > 1, "{expected} has {n} unit(s): the test needs a split");
    }
    let mut killed = None;
    for (step, n) in &steps {
        for i in (1..=*n).rev() {
            if step == "dense-pass-0" && i == *n && killed.is_none() {
                // SIGKILL while the unit computes and writes its maps.
                // Killed as soon as it has written its first map (or while it writes one):
                // halfway through its writes.
                let maps = || -> Vec<PathBuf> {
                    files(&units.join("work/dense"))
                        .into_iter()
                        .filter(|f| f.to_string_lossy().contains("pass0"))
                        .collect()
                };
                let before = maps();
                let mut child = task(&units, step, i, *n)
                    .stdout(Stdio::null())
                    .stderr(Stdio::null())
                    .spawn()
                    .expect("spawn");
                let start = Instant::now();
                while maps() == before && child.try_wait().expect("wait").is_none() {
                    assert!(start.elapsed() < Duration::from_secs(120), "no map written");
                    std::thread::sleep(Duration::from_millis(1));
                }
                let was_running = child.try_wait().expect("wait").is_none();
                child.kill().expect("SIGKILL");
                let _ = child.wait();
                assert!(was_running, "the unit finished before it could be killed");
                let written = maps().len() - before.len();
                let rows = status(&units, &[]);
                let row = rows.iter().find(|r| &r.0 == step).expect("step").1;
                assert_eq!(
                    row[5], *n,
                    "{step}: {row:?}: the killed unit must be missing"
                );
                // Nothing that a reader takes for a finished map: only whole files and
                // temporaries, which no reader opens.
                for f in files(&units.join("work/dense")) {
                    let name = f.file_name().expect("name").to_string_lossy().into_owned();
                    if name.ends_with(".exr") && !name.starts_with('.') {
                        let bytes = std::fs::read(units.join("work/dense").join(&f)).expect("read");
                        assert!(bytes.len() > 100, "{f:?}: {} bytes", bytes.len());
                    }
                }
                killed = Some(format!("{step} {i}/{n} after {written} new file(s)"));
            }
            let out = task(&units, step, i, *n).output().expect("task");
            assert!(
                out.status.success(),
                "{step} {i}/{n}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }
    println!("killed {killed:?}, then ran it again");
    // A unit run again is skipped by its record.
    let out = task(
        &units,
        "dense-fuse",
        1,
        steps.iter().find(|s| s.0 == "dense-fuse").unwrap().1,
    )
    .output()
    .expect("task");
    assert!(String::from_utf8_lossy(&out.stdout).contains("already complete"));
    for (step, row) in status(&units, &[]) {
        assert_eq!(row[1], row[0], "{step}: {row:?}");
    }
    assert_same_products(&local, &units);
}

#[test]
fn a_second_run_is_refused_naming_the_first_and_a_killed_first_leaves_no_lock() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("p");
    project(&dir);
    let d = dir.to_str().expect("utf-8");
    let mut first = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(["run", d, "--quiet"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn");
    let lock = dir.join("work/lock");
    let start = Instant::now();
    while std::fs::read_to_string(&lock).map_or(true, |t| t.is_empty()) {
        assert!(start.elapsed() < Duration::from_secs(30), "no lock taken");
        std::thread::sleep(Duration::from_millis(20));
    }
    let refused = Instant::now();
    let (ok, _, err) = timesift(&["run", d]);
    let seconds = refused.elapsed().as_secs_f64();
    assert!(!ok, "a second run was let in");
    assert!(
        err.contains(&format!("in use by timesift run (pid {}", first.id())),
        "{err}"
    );
    assert!(seconds < 5.0, "refused after {seconds:.1} s");
    // A cluster submission is refused the same way.
    let (ok, _, err) = timesift(&["run", d, "--executor", "slurm"]);
    assert!(!ok && err.contains("in use by timesift run"), "{err}");
    first.kill().expect("SIGKILL");
    let _ = first.wait();
    let (ok, out, err) = timesift(&["run", d, "--to", "features"]);
    assert!(ok, "after the holder was killed: {err}");
    assert!(out.contains("1 stages"), "{out}");
}

/// `SLURM_CONF` for the cluster of `cargo xtask slurm-up`, or why there is none.
fn slurm() -> Result<String, String> {
    let conf = std::env::var("SLURM_CONF")
        .unwrap_or_else(|_| "/tmp/timesift-slurm/slurm.conf".to_string());
    if !Path::new(&conf).is_file() {
        return Err(format!("no {conf} (start one with `cargo xtask slurm-up`)"));
    }
    let ping = Command::new("scontrol")
        .arg("ping")
        .env("SLURM_CONF", &conf)
        .output()
        .map_err(|e| format!("scontrol: {e}"))?;
    let text = String::from_utf8_lossy(&ping.stdout);
    if !ping.status.success() || !text.contains("UP") {
        return Err(format!("slurmctld does not answer: {}", text.trim()));
    }
    Ok(conf)
}

/// Waits until Slurm holds none of `jobs`.
fn drain(conf: &str, jobs: &[String]) {
    let start = Instant::now();
    loop {
        let out = Command::new("squeue")
            .args(["-h", "-j", &jobs.join(",")])
            .env("SLURM_CONF", conf)
            .output()
            .expect("squeue");
        if String::from_utf8_lossy(&out.stdout).trim().is_empty() {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(900),
            "jobs still queued after 15 min"
        );
        std::thread::sleep(Duration::from_millis(500));
    }
}

fn submit(dir: &Path, conf: &str) -> (String, Vec<String>) {
    let out = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args([
            "run",
            dir.to_str().expect("utf-8"),
            "--executor",
            "slurm",
            "--cpus-per-task",
            "1",
        ])
        .env("SLURM_CONF", conf)
        .output()
        .expect("submit");
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let jobs = text
        .lines()
        .filter_map(|l| l.strip_prefix("submitted "))
        .filter_map(|l| l.split(" as job ").nth(1))
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_string)
        .collect();
    (text, jobs)
}

#[test]
fn on_slurm_a_cancelled_task_is_all_that_is_submitted_again_and_the_products_are_the_local_ones() {
    let conf = match slurm() {
        Ok(conf) => conf,
        Err(why) => {
            println!("skipped: no Slurm cluster: {why}");
            return;
        }
    };
    let tmp = tempfile::tempdir().expect("tempdir");
    let (local, cluster) = (tmp.path().join("local"), tmp.path().join("cluster"));
    project(&local);
    copy_tree(&local, &cluster);
    let started = Instant::now();
    run_local(&local);
    let local_seconds = started.elapsed().as_secs_f64();

    let started = Instant::now();
    let (first, jobs) = submit(&cluster, &conf);
    // While Slurm holds its tasks, a second submission would run them twice: refused.
    let again = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args([
            "run",
            cluster.to_str().expect("utf-8"),
            "--executor",
            "slurm",
        ])
        .env("SLURM_CONF", &conf)
        .output()
        .expect("submit");
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(
        !again.status.success() && err.contains("still queued or running"),
        "{err}"
    );
    // The align task is one array element long enough to be caught running: cancel it.
    let align_job = first
        .lines()
        .find_map(|l| l.strip_prefix("submitted align as job "))
        .and_then(|l| l.split_whitespace().next())
        .expect("align submitted")
        .to_string();
    let element = format!("{align_job}_1");
    let start = Instant::now();
    loop {
        let out = Command::new("squeue")
            .args(["-h", "-r", "-o", "%i %T", "-j", &align_job])
            .env("SLURM_CONF", &conf)
            .output()
            .expect("squeue");
        if String::from_utf8_lossy(&out.stdout).contains(&format!("{element} RUNNING")) {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(600),
            "align never ran"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let cancelled = Command::new("scancel")
        .arg(&element)
        .env("SLURM_CONF", &conf)
        .status()
        .expect("scancel");
    assert!(cancelled.success());
    drain(&conf, &jobs);
    let env = [("SLURM_CONF", conf.as_str())];
    let rows = status(&cluster, &env);
    let before: Vec<&String> = rows.iter().map(|r| &r.0).collect();
    let mut seen_align = false;
    for (step, row) in &rows {
        if step == "align" {
            assert_eq!(
                row[5], 1,
                "align: {row:?}: the cancelled unit must be missing"
            );
            seen_align = true;
        } else if !seen_align {
            assert_eq!(
                row[1], row[0],
                "{step} (before align) must be complete: {row:?}"
            );
        } else {
            // Never ran: their dependency can no longer be met, and Slurm removed them.
            assert_eq!(
                row[5], row[0],
                "{step} (after align) must be missing: {row:?}"
            );
        }
    }
    assert!(seen_align, "{before:?}");

    let (second, jobs) = submit(&cluster, &conf);
    let submitted: Vec<&str> = second
        .lines()
        .filter_map(|l| l.strip_prefix("submitted "))
        .filter_map(|l| l.split(" as job ").next())
        .collect();
    assert_eq!(submitted.first(), Some(&"align"), "{second}");
    assert!(!submitted.contains(&"features"), "{second}");
    drain(&conf, &jobs);
    let cluster_seconds = started.elapsed().as_secs_f64();
    for (step, row) in status(&cluster, &env) {
        assert_eq!(row[1], row[0], "{step}: {row:?}");
    }
    assert_same_products(&local, &cluster);
    println!(
        "local run {local_seconds:.1} s; on Slurm, 1 CPU per task, with the cancelled align \
         submitted again: {cluster_seconds:.1} s"
    );
}
