//! Every reader of timesift as a function of bytes, so that one definition serves the libFuzzer
//! targets (`fuzz/`, nightly), the stable mutation fallback of `cargo xtask fuzz` and the test
//! that replays the committed corpus and every minimised crash on stable.
//!
//! Invariants:
//! - A target's only job is to hand the bytes to a reader the way timesift does; an `Err` is a
//!   correct answer to bad input, a panic (or a hang, or an allocation the input's size does not
//!   justify) is the bug the fuzzers look for.
//! - Readers take paths: the bytes are written to a scratch file (in `/dev/shm` when there is
//!   one) under the name the reader expects, one scratch folder per thread.
//! - Nothing here decides what is valid: that stays with the readers.

#![warn(missing_docs, unnameable_types)]

pub mod campaign;
pub mod mutate;
mod scratch;
pub mod seeds;
mod targets;

pub use targets::{Target, Verdict, run};

/// The body of a libFuzzer target: runs `bytes` through `target`'s reader and panics on a
/// finding that is not a panic already (a refusal that is not one line naming the file), so
/// that libFuzzer keeps the input.
pub fn fuzz(target: Target, bytes: &[u8]) {
    // libFuzzer's panic hook aborts on every panic; a third-party decoder's panic that
    // `decoder_guard` turns into an error is no finding, so the hook lets those pass.
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let abort = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !timesift_io::decoder_guard::guard_active() {
                abort(info);
            }
        }));
    });
    if let Err(finding) = run(target, bytes) {
        panic!("{target}: {finding}");
    }
}

/// Sets an address-space limit (`RLIMIT_AS`) on a child process: an allocation an input does
/// not justify fails there, as on a small machine, instead of succeeding on this one's memory.
pub fn limit_address_space(command: &mut std::process::Command, bytes: u64) {
    use std::os::unix::process::CommandExt;
    // SAFETY: the closure runs in the forked child before exec and only calls setrlimit, which
    // is async-signal-safe.
    unsafe {
        command.pre_exec(move || {
            let limit = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}
