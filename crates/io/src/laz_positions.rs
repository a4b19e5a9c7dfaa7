//! The positions of a layered (LAS 1.4) LAZ file, its x, y and z layers alone decompressed:
//! what gridding a dense cloud needs, several times less work than decoding every attribute.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use las::{Transform, Vector};
use rayon::prelude::*;

use crate::las_checks::{self, CheckedHeader};
use crate::{IoError, decoder_guard};

/// The positions of a layered LAZ file, its x, y and z layers alone decompressed. The chunks
/// decompress in parallel, each into a record buffer of the worker that takes it, turned into
/// positions while it is in cache: no buffer of every record is made (for a cloud of 600,000
/// points that buffer and its page faults cost as much as the conversion and half as much as
/// the decoding). Before positions are allocated, the items must be the point format's own,
/// the header's point count the chunk table's, and every chunk's bytes in the file. The
/// compressed bytes are read a group of chunks at a time (a dense cloud's LAZ file is about 0.8
/// of the positions it holds: reading it whole would nearly double the peak).
pub(crate) fn layered_laz_positions(
    path: &Path,
    header: &las::Header,
    checked: &CheckedHeader,
    vlr: laz::LazVlr,
) -> Result<Vec<[f64; 3]>, IoError> {
    /// Points decompressed per group of whole chunks: the positions grow by a group at a time.
    const BATCH: u64 = 1 << 20;
    let las_err = |e: las::Error| IoError::invalid(path, format!("cannot read LAS: {e}"));
    let laz_err = |e: laz::LasZipError| IoError::invalid(path, format!("cannot read LAZ: {e}"));
    let io_err = |e: std::io::Error| IoError::io(path, e);
    let file = std::fs::File::open(path).map_err(io_err)?;
    let file_len = file.metadata().map_err(io_err)?.len();
    let mut source = BufReader::new(file);
    let raw = las::raw::Header::read_from(&mut source).map_err(las_err)?;
    let record_len = las_checks::record_len_of_items(path, header, &vlr)?;
    source
        .seek(SeekFrom::Start(u64::from(raw.offset_to_point_data)))
        .map_err(io_err)?;
    let mut chunks = decoder_guard::catch_decoder_panic(path, "the LAZ chunk table", || {
        laz::laszip::ChunkTable::read_from(&mut source, &vlr).map_err(laz_err)
    })?
    .as_ref()
    .to_vec();
    count_points_of_chunks(path, header.number_of_points(), &vlr, &mut chunks)?;
    // The chunks follow one another from here; their bytes must lie in the file.
    let data_start = source.stream_position().map_err(io_err)?;
    let fits = chunks
        .iter()
        .try_fold(data_start, |end, chunk| end.checked_add(chunk.byte_count))
        .is_some_and(|end| end <= file_len);
    if !fits {
        return Err(IoError::invalid(path, "truncated LAZ point data"));
    }
    let decoding = PositionDecoding {
        vlr: &vlr,
        selection: laz::DecompressionSelection::xy_returns_channel().decompress_z(),
        record_len,
        transforms: header.transforms(),
    };
    let mut positions: Vec<[f64; 3]> = Vec::new();
    let mut compressed = Vec::new();
    let mut rest = chunks.as_slice();
    let mut first_chunk = 0;
    while !rest.is_empty() {
        // A group of whole chunks of about BATCH points.
        let mut n_chunks = 0;
        let mut n_points = 0u64;
        while n_chunks < rest.len() && (n_chunks == 0 || n_points < BATCH) {
            n_points += rest[n_chunks].point_count;
            n_chunks += 1;
        }
        let (group, later) = rest.split_at(n_chunks);
        rest = later;
        // The group's compressed bytes (checked above to lie in the file), cut per chunk.
        let group_bytes: u64 = group.iter().map(|c| c.byte_count).sum();
        compressed.resize(group_bytes as usize, 0);
        source.read_exact(&mut compressed).map_err(io_err)?;
        let start = positions.len();
        positions.resize(start + n_points as usize, [0.0; 3]);
        let out = &mut positions[start..];
        decoder_guard::catch_decoder_panic(path, "the LAZ decoder", || {
            decoding
                .decode_group(&compressed, group, out)
                .map_err(laz_err)
        })?;
        // Corruption that decodes is still corruption: each chunk's points in the bounds.
        let mut at = start;
        for (k, chunk) in group.iter().enumerate() {
            let end = at + chunk.point_count as usize;
            let first = at as u64;
            las_checks::check_positions(
                path,
                checked,
                &positions[at..end],
                first,
                Some(first_chunk + k),
            )?;
            at = end;
        }
        first_chunk += group.len();
    }
    Ok(positions)
}

/// Gives fixed-size chunks their point counts (the table holds none; the last chunk holds what
/// is left of the header's `point_count`), then checks that the chunks hold `point_count`.
fn count_points_of_chunks(
    path: &Path,
    point_count: u64,
    vlr: &laz::LazVlr,
    chunks: &mut [laz::laszip::ChunkTableEntry],
) -> Result<(), IoError> {
    if !vlr.uses_variable_size_chunks() {
        // Fixed-size chunks: the table holds no counts; the last chunk holds what is left.
        let n_chunks = chunks.len();
        let before_last = (n_chunks as u64).saturating_sub(1) * u64::from(vlr.chunk_size());
        match chunks.last_mut() {
            // A last chunk may be empty (a writer that closes a chunk at the end regardless).
            Some(last)
                if point_count >= before_last && point_count - before_last <= last.point_count =>
            {
                last.point_count = point_count - before_last
            }
            None if point_count == 0 => {}
            _ => {
                return Err(IoError::invalid(
                    path,
                    format!(
                        "the header's {point_count} points do not fill {} chunks of {}",
                        n_chunks,
                        vlr.chunk_size()
                    ),
                ));
            }
        }
    }
    // Counts decoded from a corrupt table can be anything: summed without overflow.
    let listed = chunks
        .iter()
        .try_fold(0u64, |sum, c| sum.checked_add(c.point_count));
    if listed != Some(point_count) {
        let listed = listed.map_or("more than 2^64".to_string(), |n| n.to_string());
        return Err(IoError::invalid(
            path,
            format!("the header counts {point_count} points, the chunk table {listed}"),
        ));
    }
    Ok(())
}

/// How a layered LAZ file's records become positions: its items, the layers decompressed (x,
/// y, z), the record length, the header's scales and offsets.
struct PositionDecoding<'a> {
    vlr: &'a laz::LazVlr,
    selection: laz::DecompressionSelection,
    record_len: usize,
    transforms: &'a Vector<Transform>,
}

impl PositionDecoding<'_> {
    /// Decompresses a group of whole chunks, whose bytes follow one another in `compressed`,
    /// into `positions` (as many as the chunks hold), the chunks in parallel.
    fn decode_group(
        &self,
        compressed: &[u8],
        group: &[laz::laszip::ChunkTableEntry],
        positions: &mut [[f64; 3]],
    ) -> Result<(), laz::LasZipError> {
        let (record_len, t) = (self.record_len, self.transforms);
        let mut jobs = Vec::with_capacity(group.len());
        let (mut unread, mut free) = (compressed, positions);
        for chunk in group {
            let (piece, bytes_left) = unread.split_at(chunk.byte_count as usize);
            let (out, points_left) = free.split_at_mut(chunk.point_count as usize);
            jobs.push((piece, chunk, out));
            (unread, free) = (bytes_left, points_left);
        }
        jobs.into_par_iter().try_for_each_init(
            Vec::new,
            |records: &mut Vec<u8>, (piece, chunk, out)| {
                records.resize(out.len() * record_len, 0);
                laz::par_decompress_selective(
                    piece,
                    records,
                    self.vlr,
                    std::slice::from_ref(chunk),
                    self.selection,
                )?;
                for (p, record) in out.iter_mut().zip(records.chunks_exact(record_len)) {
                    // Point formats 6 to 10 begin with x, y and z as little-endian i32.
                    let n = |k: usize| {
                        i32::from_le_bytes([
                            record[4 * k],
                            record[4 * k + 1],
                            record[4 * k + 2],
                            record[4 * k + 3],
                        ])
                    };
                    *p = [t.x.direct(n(0)), t.y.direct(n(1)), t.z.direct(n(2))];
                }
                Ok::<(), laz::LasZipError>(())
            },
        )
    }
}
