//! The sink the LAS writer writes through, so that a failed write is an error, not a panic.

use std::io::{Seek, SeekFrom};

/// The sink of the LAS writer: after its first failed call it accepts and discards everything.
/// The `las` writer closes itself when dropped and panics if that fails ("Error when dropping
/// the writer"): a disk that filled up would reach the user as a panic. With this sink the
/// first error returns through the writer to the caller, who removes the temporary file, and
/// the writer's drop then closes quietly.
pub(crate) struct FailOnce<W> {
    inner: W,
    failed: bool,
}

impl<W> FailOnce<W> {
    pub(crate) fn new(inner: W) -> Self {
        FailOnce {
            inner,
            failed: false,
        }
    }

    fn guard<T>(&mut self, discarded: T, result: std::io::Result<T>) -> std::io::Result<T> {
        if self.failed {
            return Ok(discarded);
        }
        result.inspect_err(|_| self.failed = true)
    }
}

impl FailOnce<std::io::BufWriter<std::fs::File>> {
    /// The file, its buffer written out.
    pub(crate) fn into_file(self) -> std::io::Result<std::fs::File> {
        self.inner.into_inner().map_err(|e| e.into_error())
    }
}

impl<W: std::io::Write> std::io::Write for FailOnce<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.failed {
            return Ok(buf.len());
        }
        let result = self.inner.write(buf);
        self.guard(buf.len(), result)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.failed {
            return Ok(());
        }
        let result = self.inner.flush();
        self.guard((), result)
    }
}

impl<W: Seek> Seek for FailOnce<W> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        if self.failed {
            return Ok(0);
        }
        let result = self.inner.seek(pos);
        self.guard(0, result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Cursor, Write};

    /// A sink that fails every call once `limit` bytes were written: a disk that filled up.
    struct FullAfter {
        inner: Cursor<Vec<u8>>,
        limit: usize,
    }

    impl Write for FullAfter {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            if self.inner.get_ref().len() + buf.len() > self.limit {
                return Err(std::io::Error::other("File too large"));
            }
            self.inner.write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Seek for FullAfter {
        fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
            self.inner.seek(pos)
        }
    }

    /// Writes 5,000 points as LAZ through [`FailOnce`] into a disk of `limit` bytes: the bytes
    /// written, or the error.
    fn write_laz(limit: usize) -> las::Result<usize> {
        let sink = FailOnce::new(FullAfter {
            inner: Cursor::new(Vec::new()),
            limit,
        });
        let mut format = las::point::Format::new(6).unwrap();
        format.is_compressed = true;
        let mut builder = las::Builder::from(las::Version::new(1, 4));
        builder.point_format = format;
        let header = builder.into_header().unwrap();
        let mut w = las::Writer::new(sink, header)?;
        for i in 0..5_000 {
            w.write_point(las::Point {
                x: i as f64,
                y: (i * 7 % 13) as f64,
                z: 1.0,
                return_number: 1,
                number_of_returns: 1,
                gps_time: Some(0.0),
                ..Default::default()
            })?;
        }
        let sink = w.into_inner()?;
        Ok(sink.inner.inner.into_inner().len())
    }

    /// The `las` writer over a sink that fills up returns the error and drops without a panic,
    /// whether the header, the point data or the closing chunk table meets the full disk.
    #[test]
    fn a_full_disk_is_an_error_and_the_writer_drops_quietly() {
        let full = write_laz(usize::MAX).unwrap();
        for limit in [0, 100, full / 2, full - 9, full - 1] {
            let err = write_laz(limit).expect_err("the disk is full").to_string();
            assert!(err.contains("File too large"), "limit {limit}: {err}");
        }
    }
}
