//! A boundary around third-party decoders that panic on some corrupt inputs.
//!
//! The `laz` crate's arithmetic decoder indexes its tables with decoded symbols unchecked: a
//! corrupt chunk panics inside it ("index out of bounds") instead of returning an error. No
//! check of the file before decoding can rule that out, since the symbols are the compressed
//! data itself. The decoder is therefore called through [`catch_decoder_panic`], which turns
//! such a panic into an error naming the file. While one runs, [`guard_active`] is true: a
//! program's panic hook can leave those panics unprinted (they are reported as errors).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use crate::IoError;

/// Guarded decoders running now.
static ACTIVE: AtomicUsize = AtomicUsize::new(0);

/// Whether a guarded decoder is running (its panics become errors).
pub fn guard_active() -> bool {
    ACTIVE.load(Ordering::SeqCst) > 0
}

/// Counts a guarded decoder while it runs, whatever way it ends.
struct Active;

impl Active {
    fn enter() -> Active {
        ACTIVE.fetch_add(1, Ordering::SeqCst);
        Active
    }
}

impl Drop for Active {
    fn drop(&mut self) {
        ACTIVE.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The text a panic was raised with (empty when its payload is not text).
pub fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_default()
}

/// Runs `decode`; a panic inside it is an error naming `path`: `what` failed on corrupt data.
pub fn catch_decoder_panic<T>(
    path: &Path,
    what: &str,
    decode: impl FnOnce() -> Result<T, IoError>,
) -> Result<T, IoError> {
    let _active = Active::enter();
    match catch_unwind(AssertUnwindSafe(decode)) {
        Ok(result) => result,
        Err(payload) => {
            let message = panic_text(payload.as_ref());
            Err(IoError::invalid(
                path,
                format!("{what} failed on corrupt data ({message})"),
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_decoder_panic_is_an_error_naming_the_file() {
        let p = Path::new("/data/dense.laz");
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let e = catch_decoder_panic(p, "the LAZ decoder", || {
            let table = [1u32; 3];
            // Out of bounds while the guard is active, as a decoded symbol can be.
            let i = table.len() + usize::from(guard_active()) - 1;
            Ok(table[i])
        })
        .unwrap_err()
        .to_string();
        std::panic::set_hook(hook);
        assert!(
            e.contains("dense.laz") && e.contains("index out of bounds"),
            "{e}"
        );
        assert!(!guard_active());
        assert_eq!(catch_decoder_panic(p, "x", || Ok(7)).unwrap(), 7);
    }
}
