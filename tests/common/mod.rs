//! Helpers shared by the end-to-end tests.

use std::process::Command;

/// Runs the `timesift` binary: (success, stdout, stderr).
pub fn timesift(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_timesift"))
        .args(args)
        .output()
        .expect("the binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
