//! What a LAS or LAZ file claims, checked before the `las` and `laz` crates act on it: they
//! allocate from the header's point count, an extended record's length and the chunk table's
//! entry count without comparing them with the file, and they accept decoded points wherever
//! they fall. Corruption that decodes is still corruption: points outside the header's bounds
//! are an error naming the chunk.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use crate::{IoError, budget};

/// The most bytes of point records a byte of a LAZ file decodes to (a typical cloud is 5 to
/// 10; a cloud of identical points reaches a few thousand).
const MAX_LAZ_EXPANSION: u64 = 16_384;

/// The length of point format 0's record, the shortest.
const MIN_RECORD_LEN: u64 = 20;

/// Length of an extended variable-length record's header.
const EVLR_HEADER_LEN: u64 = 60;

/// Facts of a file's header, checked against the file.
#[derive(Debug, Clone, Copy)]
pub(crate) struct CheckedHeader {
    /// Points the header counts.
    pub points: u64,
    /// Where the point data begins.
    pub offset_to_point_data: u64,
    /// The file's length.
    pub file_len: u64,
    /// Whether the points are LAZ-compressed.
    pub compressed: bool,
    /// The stated bounds (min, max per axis), when the header states any.
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// The coordinate resolution per axis (the scale factors).
    pub scale: [f64; 3],
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(b)
}

/// Reads the raw header of `path` and checks what the readers will trust: finite positive
/// scales, finite offsets, the end of the point data computable and (uncompressed) in the file,
/// an extended record that lies in the file, and the memory the points will take.
pub(crate) fn check_header(path: &Path) -> Result<CheckedHeader, IoError> {
    let invalid = |message: String| IoError::invalid(path, message);
    let las_err = |e: las::Error| IoError::invalid(path, format!("cannot read LAS: {e}"));
    let file = File::open(path).map_err(|e| IoError::io(path, e))?;
    let file_len = file.metadata().map_err(|e| IoError::io(path, e))?.len();
    let mut source = BufReader::new(file);
    let raw = las::raw::Header::read_from(&mut source).map_err(las_err)?;
    let scale = [raw.x_scale_factor, raw.y_scale_factor, raw.z_scale_factor];
    let offset = [raw.x_offset, raw.y_offset, raw.z_offset];
    if scale.iter().any(|s| !(s.is_finite() && *s > 0.0)) || offset.iter().any(|o| !o.is_finite()) {
        return Err(invalid(format!(
            "scale factors {scale:?} and offsets {offset:?}: positive finite scales and finite \
             offsets were expected"
        )));
    }
    // LAS 1.4 states the count twice (legacy 32-bit and 64-bit); readers differ in which
    // they believe, so the larger one is checked.
    let points = raw
        .large_file
        .map_or(0, |l| l.number_of_point_records)
        .max(u64::from(raw.number_of_point_records));
    let compressed = raw.point_data_record_format & 0xC0 != 0;
    let record_len = u64::from(raw.point_data_record_length);
    // The shortest record of any point format is 20 bytes; a shorter one makes every count
    // check below vacuous.
    if points > 0 && record_len < MIN_RECORD_LEN {
        return Err(invalid(format!(
            "{points} points of {record_len}-byte records; a LAS record has at least \
             {MIN_RECORD_LEN} bytes"
        )));
    }
    let offset_to_point_data = u64::from(raw.offset_to_point_data);
    let end_of_points = points
        .checked_mul(record_len)
        .and_then(|n| n.checked_add(offset_to_point_data));
    let fits = match end_of_points {
        None => false,
        Some(end) => compressed || end <= file_len,
    };
    if offset_to_point_data > file_len || !fits {
        return Err(invalid(format!(
            "the header counts {points} points of {record_len} bytes from byte \
             {offset_to_point_data}; the file has {file_len} bytes"
        )));
    }
    if let Some(evlr) = raw.evlr.filter(|e| e.number_of_evlrs > 0) {
        let start = evlr.start_of_first_evlr;
        let mut head = [0u8; EVLR_HEADER_LEN as usize];
        let read = source
            .seek(SeekFrom::Start(start))
            .and_then(|_| source.read_exact(&mut head));
        let len = read.ok().map(|()| u64_at(&head, 20));
        let in_file = len
            .and_then(|l| start.checked_add(EVLR_HEADER_LEN)?.checked_add(l))
            .is_some_and(|end| end <= file_len);
        if !in_file {
            return Err(invalid(format!(
                "the extended record at byte {start} does not lie in the file's {file_len} bytes"
            )));
        }
    }
    // LAZ makes a few bytes of a point at best; points of constant coordinates and attributes
    // still take a little of the arithmetic coder's output each.
    budget::check_expansion(
        path,
        points.saturating_mul(record_len + 3 * 8 + 8),
        file_len,
        MAX_LAZ_EXPANSION,
        "the point records",
    )?;
    // The decoded records and their positions (what reading every attribute holds at once).
    budget::ensure_allocatable(
        path,
        points.saturating_mul(record_len + 3 * 8 + 8),
        "the points",
    )?;
    let min = [raw.min_x, raw.min_y, raw.min_z];
    let max = [raw.max_x, raw.max_y, raw.max_z];
    // Some writers leave the bounds at zero, and those of no point are not a box (las writes
    // +inf to -inf): nothing is stated then.
    let stated = points > 0 && min.iter().chain(&max).any(|v| *v != 0.0);
    let bounds = stated.then_some((min, max));
    if let Some((min, max)) = bounds
        && (0..3).any(|k| !(min[k].is_finite() && max[k].is_finite() && min[k] <= max[k]))
    {
        return Err(invalid(format!(
            "the header's bounds {min:?} to {max:?} are not a box"
        )));
    }
    Ok(CheckedHeader {
        points,
        offset_to_point_data,
        file_len,
        compressed,
        bounds,
        scale,
    })
}

/// Checks the chunk table a LAZ file's point data begins by pointing at, before the `laz`
/// crate reads it (and allocates an entry per chunk the table claims): the table must lie in
/// the file after the point data, and claim no more chunks than the bytes between can hold.
pub(crate) fn check_chunk_table(path: &Path, header: &CheckedHeader) -> Result<(), IoError> {
    let invalid = |message: String| IoError::invalid(path, message);
    let io = |e: std::io::Error| IoError::io(path, e);
    let mut file = File::open(path).map_err(io)?;
    let data_start = header.offset_to_point_data;
    let mut word = [0u8; 8];
    file.seek(SeekFrom::Start(data_start)).map_err(io)?;
    if file.read_exact(&mut word).is_err() {
        return Err(invalid(format!(
            "the LAZ point data at byte {data_start} ends before its chunk table's offset"
        )));
    }
    let mut table = i64::from_le_bytes(word);
    if table == -1 {
        // Written by a streaming writer: the offset is the file's last 8 bytes.
        let last = header.file_len.checked_sub(8).ok_or_else(|| {
            invalid("the LAZ file is too short for its chunk table's offset".to_string())
        })?;
        file.seek(SeekFrom::Start(last)).map_err(io)?;
        file.read_exact(&mut word).map_err(io)?;
        table = i64::from_le_bytes(word);
    }
    let table = u64::try_from(table).unwrap_or(u64::MAX);
    let table_in_file = table
        .checked_add(8)
        .is_some_and(|end| end <= header.file_len);
    if table < data_start + 8 || !table_in_file {
        return Err(invalid(format!(
            "the LAZ chunk table's offset {table} lies outside the point data (bytes \
             {data_start} to {})",
            header.file_len
        )));
    }
    file.seek(SeekFrom::Start(table + 4)).map_err(io)?;
    let mut count = [0u8; 4];
    file.read_exact(&mut count).map_err(io)?;
    let chunks = u64::from(u32::from_le_bytes(count));
    // Every chunk but an empty last one holds a point and takes a byte of the point data.
    let room = (table - (data_start + 8)).min(header.points) + 1;
    if chunks > room {
        return Err(invalid(format!(
            "the LAZ chunk table claims {chunks} chunks; the point data has room for {room}"
        )));
    }
    Ok(())
}

/// Checks decoded positions against the header's bounds, allowing a step of the coordinate
/// resolution (bounds written from unrounded coordinates). `first` is the index of the first
/// position in the file, `chunk` the LAZ chunk they came from, if known.
pub(crate) fn check_positions(
    path: &Path,
    header: &CheckedHeader,
    positions: &[[f64; 3]],
    first: u64,
    chunk: Option<usize>,
) -> Result<(), IoError> {
    let Some((min, max)) = header.bounds else {
        return Ok(());
    };
    let slack: [f64; 3] =
        std::array::from_fn(|k| header.scale[k] + 1e-9 * min[k].abs().max(max[k].abs()));
    let outside = positions
        .iter()
        .position(|p| (0..3).any(|k| !(p[k] >= min[k] - slack[k] && p[k] <= max[k] + slack[k])));
    match outside {
        None => Ok(()),
        Some(i) => {
            let p = positions[i];
            let place = chunk
                .map(|c| format!("chunk {c} decodes "))
                .unwrap_or_default();
            Err(IoError::invalid(
                path,
                format!(
                    "{place}point {} at ({:.3}, {:.3}, {:.3}) outside the header's bounds \
                     ({:.3}, {:.3}, {:.3}) to ({:.3}, {:.3}, {:.3}): the file is corrupt",
                    first + i as u64,
                    p[0],
                    p[1],
                    p[2],
                    min[0],
                    min[1],
                    min[2],
                    max[0],
                    max[1],
                    max[2]
                ),
            ))
        }
    }
}

/// The length of the file's point records, after checking that its LAZ items are the
/// point format's own. The decoder lays out each item at its own size, whatever the file
/// states: items other than the point format's own would be misread. (las derived the format's
/// extra bytes from the header's record length, so the expected items add up to it.)
pub(crate) fn record_len_of_items(
    path: &Path,
    header: &las::Header,
    vlr: &laz::LazVlr,
) -> Result<usize, IoError> {
    let format = header.point_format();
    let expected = format
        .to_u8()
        .ok()
        .and_then(|id| {
            laz::LazItemRecordBuilder::default_for_point_format_id(id, format.extra_bytes).ok()
        })
        .unwrap_or_default();
    let layout = |items: &[laz::LazItem]| -> Vec<(laz::LazItemType, u16)> {
        items.iter().map(|i| (i.item_type(), i.size())).collect()
    };
    let record_len = usize::from(format.len());
    if expected.is_empty() || layout(vlr.items()) != layout(&expected) {
        return Err(IoError::invalid(
            path,
            format!("its LAZ items do not make the header's {record_len}-byte records"),
        ));
    }
    Ok(record_len)
}

/// The layers an item of a layered (LAS 1.4) LAZ record has: each chunk stores its first
/// point raw, the point count, then one byte length per layer (the `laz` crate allocates each
/// length before reading it). `None` for point-wise items (formats 0 to 5).
fn layers_of(item: &laz::LazItem) -> Option<u64> {
    match item.item_type() {
        laz::LazItemType::Point14 => Some(9),
        laz::LazItemType::RGB14 | laz::LazItemType::WavePacket14 => Some(1),
        laz::LazItemType::RGBNIR14 => Some(2),
        laz::LazItemType::Byte14(n) => Some(u64::from(n)),
        _ => None,
    }
}

/// The most points a LAZ chunk may hold: writers use 50,000; the decompressor allocates a
/// chunk's records at once.
const MAX_CHUNK_POINTS: u64 = 1 << 24;

/// Checks every chunk of a LAZ file before it is decompressed: a chunk holds at most
/// [`MAX_CHUNK_POINTS`] points, the chunks hold the header's count, lie in the file, and (in a
/// layered file) their layer lengths add up to no more than the chunk's bytes (a corrupt length
/// is otherwise allocated as claimed, up to 4 GiB per layer, by the decompressor).
pub(crate) fn check_chunks(
    path: &Path,
    header: &CheckedHeader,
    vlr: &laz::LazVlr,
) -> Result<(), IoError> {
    let invalid = |message: String| IoError::invalid(path, message);
    let io = |e: std::io::Error| IoError::io(path, e);
    let mut file = BufReader::new(File::open(path).map_err(io)?);
    file.seek(SeekFrom::Start(header.offset_to_point_data))
        .map_err(io)?;
    // The table is compressed with the same arithmetic coder as the points: corrupt, it can
    // trip the decoder's own assertions.
    let table = crate::decoder_guard::catch_decoder_panic(path, "the LAZ chunk table", || {
        laz::laszip::ChunkTable::read_from(&mut file, vlr)
            .map_err(|e| invalid(format!("cannot read LAZ: {e}")))
    })?;
    let chunks = table.as_ref();
    let largest = if vlr.uses_variable_size_chunks() {
        let mut sum = 0u64;
        let mut largest = 0;
        for (k, chunk) in chunks.iter().enumerate() {
            if chunk.point_count > MAX_CHUNK_POINTS {
                return Err(invalid(format!(
                    "LAZ chunk {k} claims {} points; at most {MAX_CHUNK_POINTS} are read",
                    chunk.point_count
                )));
            }
            sum += chunk.point_count;
            largest = largest.max(chunk.point_count);
        }
        if sum != header.points {
            return Err(invalid(format!(
                "the header counts {} points, the LAZ chunk table {sum}",
                header.points
            )));
        }
        largest
    } else {
        let size = u64::from(vlr.chunk_size());
        if size == 0 || size > MAX_CHUNK_POINTS {
            return Err(invalid(format!(
                "LAZ chunks of {size} points; from 1 to {MAX_CHUNK_POINTS} are read"
            )));
        }
        if (chunks.len() as u64).saturating_mul(size) < header.points {
            return Err(invalid(format!(
                "the header's {} points do not fit in {} chunks of {size}",
                header.points,
                chunks.len()
            )));
        }
        size
    };
    // A chunk's records are allocated at once, whatever the chunk holds.
    budget::check_expansion(
        path,
        largest.saturating_mul(vlr.items_size()),
        header.file_len,
        MAX_LAZ_EXPANSION,
        "a LAZ chunk",
    )?;
    // A group of chunks decompressed at once, and the last one's records kept aside.
    budget::ensure_allocatable(
        path,
        largest.saturating_mul(vlr.items_size()).saturating_mul(4),
        "a LAZ chunk",
    )?;
    check_layers(path, header, vlr, chunks, &mut file)
}

/// The layer lengths of each chunk of a layered file against the chunk's bytes.
fn check_layers(
    path: &Path,
    header: &CheckedHeader,
    vlr: &laz::LazVlr,
    chunks: &[laz::laszip::ChunkTableEntry],
    file: &mut BufReader<File>,
) -> Result<(), IoError> {
    let invalid = |message: String| IoError::invalid(path, message);
    let io = |e: std::io::Error| IoError::io(path, e);
    let Some(layers) = vlr
        .items()
        .iter()
        .map(layers_of)
        .try_fold(0u64, |sum, n| Some(sum + n?))
    else {
        return Ok(());
    };
    let first_point: u64 = vlr.items().iter().map(|i| u64::from(i.size())).sum();
    // The first point, the point count, the layer lengths.
    let head_len = first_point + 4 + 4 * layers;
    let mut at = header.offset_to_point_data + 8;
    let mut head = vec![0u8; head_len as usize];
    for (k, chunk) in chunks.iter().enumerate() {
        let end = at
            .checked_add(chunk.byte_count)
            .filter(|end| *end <= header.file_len)
            .ok_or_else(|| {
                invalid(format!(
                    "LAZ chunk {k} of {} bytes at byte {at} does not lie in the file",
                    chunk.byte_count
                ))
            })?;
        if chunk.byte_count > 0 {
            if chunk.byte_count < head_len {
                return Err(invalid(format!(
                    "LAZ chunk {k} has {} bytes, fewer than its first point and layer table",
                    chunk.byte_count
                )));
            }
            file.seek(SeekFrom::Start(at)).map_err(io)?;
            file.read_exact(&mut head).map_err(io)?;
            let claimed: u64 = head[(first_point + 4) as usize..]
                .chunks_exact(4)
                .map(|b| u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
                .sum();
            if claimed > chunk.byte_count - head_len {
                return Err(invalid(format!(
                    "LAZ chunk {k}: its layers claim {claimed} bytes, the chunk holds {}",
                    chunk.byte_count - head_len
                )));
            }
        }
        at = end;
    }
    Ok(())
}
