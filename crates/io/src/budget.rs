//! Sizes a file claims, checked before anything is allocated for them.
//!
//! A header states a width, a height, a point count; a corrupt or hostile file can state any
//! number, and an allocation that fails aborts the process instead of returning an error. So
//! every reader bounds what a header claims (cells of a raster, [`MAX_CELLS`]) and, before it
//! allocates a claimed size, asks here whether that much memory can be had at all.

use std::path::Path;

use crate::IoError;

/// The most cells (pixels, samples of a map) a raster or image may claim: 2³¹, what every
/// product of timesift stays under (a 46,000-pixel square).
pub const MAX_CELLS: u64 = 1 << 31;

/// The length of one side of an image or raster that no file needs: 2³⁰ pixels.
pub const MAX_SIDE: u64 = 1 << 30;

/// Checks that a `width` × `height` grid is one a file may claim: neither side zero or over
/// [`MAX_SIDE`], at most [`MAX_CELLS`] cells. `what` names the grid in the error.
pub fn check_cells(path: &Path, width: u64, height: u64, what: &str) -> Result<u64, IoError> {
    let cells = width.saturating_mul(height);
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE || cells > MAX_CELLS {
        return Err(IoError::invalid(
            path,
            format!(
                "{what} claims {width} × {height} cells; at most {MAX_CELLS} cells are read \
                 (a corrupt header, or a grid to cut into tiles first)"
            ),
        ));
    }
    Ok(cells)
}

/// Refuses a decoded size no file of `file_len` bytes can hold: more than `ratio` decoded bytes
/// per byte of the file (the most its compression makes of a byte, with room), plus a MiB.
/// A claim beyond that is a corrupt header, whatever memory there is; it is refused before
/// anything is allocated or tried (an allocator under a sanitizer or a fuzzer's limit treats
/// a huge request as a failure in itself).
pub fn check_expansion(
    path: &Path,
    decoded: u64,
    file_len: u64,
    ratio: u64,
    what: &str,
) -> Result<(), IoError> {
    if decoded > ratio.saturating_mul(file_len).saturating_add(1 << 20) {
        return Err(IoError::invalid(
            path,
            format!(
                "{what} claims {decoded} bytes decoded, more than the file's {file_len} bytes \
                 can hold (a corrupt header)"
            ),
        ));
    }
    Ok(())
}

/// The most bytes a byte of a compressed raster or image decodes to: LZW's longest code
/// (about 2,730 to 1) with room; deflate stops near 1,032 to 1, PackBits at 64, JPEG lower.
pub const MAX_RASTER_EXPANSION: u64 = 4096;

/// Fails with an error naming `path` when `bytes` of memory cannot be allocated now: tried and
/// released at once, so that a later allocation of that size (inside a decoder that would
/// abort on failure) is known to be possible. Under an address-space or container limit this
/// is what turns a header's huge claim into one line instead of an abort.
pub fn ensure_allocatable(path: &Path, bytes: u64, what: &str) -> Result<(), IoError> {
    let refused = || {
        IoError::invalid(
            path,
            format!(
                "{what} needs {:.2} GiB of memory, which cannot be allocated",
                bytes as f64 / f64::from(1u32 << 30)
            ),
        )
    };
    let bytes = usize::try_from(bytes)
        .ok()
        .filter(|&b| b <= isize::MAX as usize)
        .ok_or_else(refused)?;
    let mut probe: Vec<u8> = Vec::new();
    probe.try_reserve_exact(bytes).map_err(|_| refused())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn claimed_grids_are_bounded() {
        let p = Path::new("/data/dem.tif");
        assert_eq!(check_cells(p, 1000, 2000, "the DEM").unwrap(), 2_000_000);
        for (w, h) in [
            (0, 10),
            (10, 0),
            (1 << 31, 1),
            (65_536, 65_536),
            (u64::MAX, u64::MAX),
        ] {
            let e = check_cells(p, w, h, "the DEM").unwrap_err().to_string();
            assert!(e.contains("dem.tif") && e.contains("the DEM claims"), "{e}");
        }
    }

    #[test]
    fn claims_beyond_what_the_file_holds_are_refused() {
        let p = Path::new("/data/scan.jpg");
        assert!(check_expansion(p, 4096 * 1000 + (1 << 20), 1000, 4096, "the image").is_ok());
        let e = check_expansion(p, 4096 * 1000 + (1 << 20) + 1, 1000, 4096, "the image")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("scan.jpg") && e.contains("the image claims"),
            "{e}"
        );
        assert!(check_expansion(p, u64::MAX, u64::MAX, u64::MAX, "x").is_ok());
    }

    #[test]
    fn impossible_allocations_are_errors_not_aborts() {
        let p = Path::new("/data/x.laz");
        assert!(ensure_allocatable(p, 1 << 20, "the points").is_ok());
        let e = ensure_allocatable(p, u64::MAX, "the points")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("x.laz") && e.contains("cannot be allocated"),
            "{e}"
        );
        // More than any address space holds (2^62 bytes): refused by the allocator itself.
        assert!(ensure_allocatable(p, 1 << 62, "the points").is_err());
    }
}
