//! The downstream example (`examples/downstream/`): a crate outside the workspace, depending on
//! timesift's crates by path, swaps in a feature extractor of its own and runs timesift's
//! matching and orientation on it. Built and run here; it checks in the orientation result that
//! every observation is one of its extractor's keypoints, and this test checks what it printed.

use std::path::{Path, PathBuf};
use std::process::Command;

#[test]
fn a_crate_outside_the_workspace_orients_a_block_with_its_own_feature_extractor() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest = root.join("examples/downstream/Cargo.toml");
    // The workspace's target folder and test profile: the dependencies compiled for the
    // workspace's tests are reused (cargo releases its build lock before it runs tests).
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target"));
    let dir = tempfile::tempdir().expect("tempdir");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let output = Command::new(cargo)
        .args([
            "run",
            "--quiet",
            "--locked",
            "--profile",
            "test",
            "--manifest-path",
        ])
        .arg(&manifest)
        .arg("--target-dir")
        .arg(&target)
        .arg("--")
        .arg(dir.path())
        .output()
        .expect("cargo runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    println!("{stdout}");
    assert!(output.status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("ok: the orientation is made of even-sift's keypoints"),
        "{stdout}"
    );
    assert!(
        stdout.contains(" 0 not from even-sift, 0 in a grid cell already observed"),
        "{stdout}"
    );
    // The extractor's name is recorded with the features, so the built-in extractor of a later
    // `timesift run` would redo them.
    let settings =
        std::fs::read_to_string(dir.path().join("work/features/settings.json")).expect("settings");
    assert!(settings.contains("even-sift"), "{settings}");
}
