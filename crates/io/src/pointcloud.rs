//! Point clouds in LAS 1.4 / LAZ: positions in f64 through the file's offset and scale, optional RGB,
//! named extra attributes (the LAS "extra bytes"), and the CRS as a WKT record.
//!
//! LAS stores integers scaled and offset; the writer takes the scale (default 1 mm) and puts the
//! offset at the cloud's minimum corner rounded to the metre, so UTM-sized coordinates keep full
//! precision. The format (LAS or LAZ) follows the file extension.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use las::{
    Builder, Color, Point, PointData, Reader, Transform, Vector, Version, Vlr, Writer,
    point::Format,
};

use rayon::prelude::*;

use crate::coords::Crs;
use crate::{IoError, fsutil};

/// Values of one extra attribute, one per point.
#[derive(Debug, Clone, PartialEq)]
pub enum AttributeValues {
    /// Unsigned bytes (flags, classes).
    U8(Vec<u8>),
    /// Single-precision floats (distances, uncertainties).
    F32(Vec<f32>),
    /// Double-precision floats.
    F64(Vec<f64>),
}

impl AttributeValues {
    fn len(&self) -> usize {
        match self {
            AttributeValues::U8(v) => v.len(),
            AttributeValues::F32(v) => v.len(),
            AttributeValues::F64(v) => v.len(),
        }
    }
    fn size(&self) -> usize {
        match self {
            AttributeValues::U8(_) => 1,
            AttributeValues::F32(_) => 4,
            AttributeValues::F64(_) => 8,
        }
    }
    /// LAS 1.4 extra-bytes data type code.
    fn type_code(&self) -> u8 {
        match self {
            AttributeValues::U8(_) => 1,
            AttributeValues::F32(_) => 9,
            AttributeValues::F64(_) => 10,
        }
    }
    fn push_le(&self, i: usize, out: &mut Vec<u8>) {
        match self {
            AttributeValues::U8(v) => out.push(v[i]),
            AttributeValues::F32(v) => out.extend_from_slice(&v[i].to_le_bytes()),
            AttributeValues::F64(v) => out.extend_from_slice(&v[i].to_le_bytes()),
        }
    }
}

/// A named per-point attribute.
#[derive(Debug, Clone, PartialEq)]
pub struct ExtraAttribute {
    /// Attribute name (at most 32 bytes).
    pub name: String,
    /// The values.
    pub values: AttributeValues,
}

/// A point cloud with optional colours and attributes.
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud {
    /// Positions in the CRS, metres.
    pub positions: Vec<[f64; 3]>,
    /// 16-bit RGB colours, one per point.
    pub colors: Option<Vec<[u16; 3]>>,
    /// Extra attributes, each with one value per point.
    pub attributes: Vec<ExtraAttribute>,
    /// The CRS.
    pub crs: Crs,
}

/// Options of the LAS writer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LasWriteOptions {
    /// Coordinate resolution in metres (the LAS scale), per axis.
    pub scale: [f64; 3],
}

impl Default for LasWriteOptions {
    fn default() -> Self {
        LasWriteOptions { scale: [0.001; 3] }
    }
}

const EXTRA_BYTES_USER: &str = "LASF_Spec";
const EXTRA_BYTES_RECORD: u16 = 4;
const DESCRIPTOR_LEN: usize = 192;

fn extra_bytes_vlr(attributes: &[ExtraAttribute]) -> Vlr {
    let mut data = Vec::with_capacity(attributes.len() * DESCRIPTOR_LEN);
    for a in attributes {
        let mut d = [0u8; DESCRIPTOR_LEN];
        d[2] = a.values.type_code();
        let name = a.name.as_bytes();
        d[4..4 + name.len().min(32)].copy_from_slice(&name[..name.len().min(32)]);
        data.extend_from_slice(&d);
    }
    Vlr {
        user_id: EXTRA_BYTES_USER.to_string(),
        record_id: EXTRA_BYTES_RECORD,
        description: "extra attributes".to_string(),
        data,
    }
}

/// Writes a LAS 1.4 file (LAZ when the extension is `.laz`), atomically.
pub fn write_las(
    path: &Path,
    cloud: &PointCloud,
    options: &LasWriteOptions,
) -> Result<(), IoError> {
    check_writable(path, cloud, options)?;
    let offset = centred_offset(path, cloud, options)?;
    let extra: usize = cloud.attributes.iter().map(|a| a.values.size()).sum();
    let header = las_header(path, cloud, options, offset, extra)?;
    let tmp = fsutil::temporary_sibling(path);
    let written = write_las_points(path, &tmp, header, cloud, extra);
    fsutil::commit_temporary(&tmp, path, written)
}

/// Whether `cloud` can be written: one colour and attribute value per point, attribute names
/// of 1 to 32 bytes, a positive scale.
fn check_writable(
    path: &Path,
    cloud: &PointCloud,
    options: &LasWriteOptions,
) -> Result<(), IoError> {
    let n = cloud.positions.len();
    if cloud.colors.as_ref().is_some_and(|c| c.len() != n)
        || cloud.attributes.iter().any(|a| a.values.len() != n)
    {
        return Err(IoError::invalid(
            path,
            "colours and attributes must have one value per point",
        ));
    }
    if let Some(a) = cloud
        .attributes
        .iter()
        .find(|a| a.name.len() > 32 || a.name.is_empty())
    {
        return Err(IoError::invalid(
            path,
            format!("attribute name \"{}\" must have 1 to 32 bytes", a.name),
        ));
    }
    if options.scale.iter().any(|s| !(*s > 0.0)) {
        return Err(IoError::invalid(path, "LAS scale must be positive"));
    }
    Ok(())
}

/// The LAS offset of each axis (0 for an empty cloud); an error for a non-finite coordinate or
/// an extent too wide for the scale.
fn centred_offset(
    path: &Path,
    cloud: &PointCloud,
    options: &LasWriteOptions,
) -> Result<[f64; 3], IoError> {
    let mut min = [f64::INFINITY; 3];
    let mut max = [f64::NEG_INFINITY; 3];
    for p in &cloud.positions {
        for k in 0..3 {
            if !p[k].is_finite() {
                return Err(IoError::invalid(path, "non-finite point coordinate"));
            }
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    // Offset at the centre of the extent (rounded to the metre): LAS stores i32 counts of the
    // scale from the offset, so the extent may reach ±2^31 scale units either side.
    let mut offset = [0.0; 3];
    for k in 0..3 {
        if min[k].is_finite() {
            offset[k] = (0.5 * (min[k] + max[k])).round();
            let half = (max[k] - offset[k]).max(offset[k] - min[k]);
            if half / options.scale[k] > i32::MAX as f64 - 1.0 {
                return Err(IoError::invalid(
                    path,
                    format!(
                        "the cloud spans {:.1} m along axis {k}, too wide for a LAS scale of {} m; use a coarser scale",
                        max[k] - min[k],
                        options.scale[k]
                    ),
                ));
            }
        }
    }
    Ok(offset)
}

/// The LAS 1.4 header of `cloud`: point format 6 (7 with colours) with `extra` bytes of
/// attributes described in their record, the scale and `offset`, the CRS's WKT.
fn las_header(
    path: &Path,
    cloud: &PointCloud,
    options: &LasWriteOptions,
    offset: [f64; 3],
    extra: usize,
) -> Result<las::Header, IoError> {
    let mut builder = Builder::from(Version::new(1, 4));
    builder.generating_software = format!("timesift {}", env!("CARGO_PKG_VERSION"));
    let mut format = Format::new(if cloud.colors.is_some() { 7 } else { 6 })
        .map_err(|e| IoError::invalid(path, e.to_string()))?;
    format.extra_bytes = extra as u16;
    builder.point_format = format;
    builder.transforms = Vector {
        x: Transform {
            scale: options.scale[0],
            offset: offset[0],
        },
        y: Transform {
            scale: options.scale[1],
            offset: offset[1],
        },
        z: Transform {
            scale: options.scale[2],
            offset: offset[2],
        },
    };
    if !cloud.attributes.is_empty() {
        builder.vlrs.push(extra_bytes_vlr(&cloud.attributes));
    }
    let mut header = builder
        .into_header()
        .map_err(|e| IoError::invalid(path, format!("LAS header: {e}")))?;
    if let Crs::Epsg(code) = cloud.crs {
        let wkt = cloud.crs.wkt().ok_or_else(|| IoError::Crs {
            crs: format!("EPSG:{code}"),
            message: "no WKT definition known for the LAS header".to_string(),
        })?;
        header
            .set_wkt_crs(wkt.as_bytes().to_vec())
            .map_err(|e| IoError::invalid(path, format!("LAS CRS: {e}")))?;
    }
    Ok(header)
}

/// Writes the points of `cloud` to `tmp` under `header` (errors name `path`, the file it
/// becomes): single returns, GPS time 0, colours, the attributes' `extra` bytes.
fn write_las_points(
    path: &Path,
    tmp: &Path,
    header: las::Header,
    cloud: &PointCloud,
    extra: usize,
) -> Result<(), IoError> {
    let las_err = |e: las::Error| IoError::invalid(path, format!("cannot write LAS: {e}"));
    let mut writer = Writer::from_path(tmp, header).map_err(las_err)?;
    let mut bytes = Vec::with_capacity(extra);
    for i in 0..cloud.positions.len() {
        bytes.clear();
        for a in &cloud.attributes {
            a.values.push_le(i, &mut bytes);
        }
        let [x, y, z] = cloud.positions[i];
        let point = Point {
            x,
            y,
            z,
            return_number: 1,
            number_of_returns: 1,
            gps_time: Some(0.0),
            color: cloud.colors.as_ref().map(|c| Color {
                red: c[i][0],
                green: c[i][1],
                blue: c[i][2],
            }),
            extra_bytes: bytes.clone(),
            ..Default::default()
        };
        writer.write_point(point).map_err(las_err)?;
    }
    writer.close().map_err(las_err)
}

/// One attribute's layout read from the extra-bytes record.
struct Descriptor {
    name: String,
    type_code: u8,
}

fn descriptors(path: &Path, vlr: &Vlr) -> Result<Vec<Descriptor>, IoError> {
    if vlr.data.len() % DESCRIPTOR_LEN != 0 {
        return Err(IoError::invalid(
            path,
            "extra-bytes record has a partial descriptor",
        ));
    }
    Ok(vlr
        .data
        .chunks_exact(DESCRIPTOR_LEN)
        .map(|d| Descriptor {
            name: String::from_utf8_lossy(&d[4..36])
                .trim_end_matches('\0')
                .to_string(),
            type_code: d[2],
        })
        .collect())
}

/// Reads a LAS or LAZ file: positions, colours when the format has them, the extra attributes of
/// type u8, f32 and f64 described by an extra-bytes record, and an EPSG CRS when the WKT names one.
pub fn read_las(path: &Path) -> Result<PointCloud, IoError> {
    let las_err = |e: las::Error| IoError::invalid(path, format!("cannot read LAS: {e}"));
    let mut reader = Reader::from_path(path).map_err(las_err)?;
    let header = reader.header().clone();
    let descs = match header
        .all_vlrs()
        .find(|v| v.user_id == EXTRA_BYTES_USER && v.record_id == EXTRA_BYTES_RECORD)
    {
        Some(v) => descriptors(path, v)?,
        None => Vec::new(),
    };
    let mut attributes = Vec::with_capacity(descs.len());
    for d in &descs {
        let values = match d.type_code {
            1 => AttributeValues::U8(Vec::new()),
            9 => AttributeValues::F32(Vec::new()),
            10 => AttributeValues::F64(Vec::new()),
            other => {
                return Err(IoError::unsupported(
                    path,
                    "LAS extra-bytes type",
                    format!(
                        "attribute \"{}\" has data type {other}; u8, f32 and f64 are read",
                        d.name
                    ),
                ));
            }
        };
        attributes.push(ExtraAttribute {
            name: d.name.clone(),
            values,
        });
    }
    let crs = crs_of(&header);
    let has_color = header.point_format().has_color;
    let data = reader.read_all().map_err(las_err)?;
    // Column by column from the decompressed records: materialising a `las::Point` per record
    // allocates its extra bytes, which cost more than the decompression itself.
    let mut positions = Vec::with_capacity(data.len());
    positions.extend(positions_of(&data));
    let mut colors = has_color.then(|| Vec::with_capacity(data.len()));
    if let (Some(colors), Some(rgb)) = (colors.as_mut(), data.rgb()) {
        colors.extend(rgb.map(|(r, g, b)| [r, g, b]));
    }
    let record_len = data.record_len();
    let extra_len = usize::from(data.format().extra_bytes);
    let needed: usize = attributes.iter().map(|a| a.values.size()).sum();
    if needed > extra_len {
        return Err(IoError::invalid(
            path,
            "point record shorter than its extra attributes",
        ));
    }
    if needed > 0 {
        let extra_start = record_len - extra_len;
        for record in data.raw_bytes().chunks_exact(record_len) {
            let mut bytes = &record[extra_start..];
            for a in attributes.iter_mut() {
                let (value, rest) = bytes.split_at(a.values.size());
                bytes = rest;
                match &mut a.values {
                    AttributeValues::U8(v) => v.push(value[0]),
                    AttributeValues::F32(v) => {
                        let mut b = [0u8; 4];
                        b.copy_from_slice(value);
                        v.push(f32::from_le_bytes(b))
                    }
                    AttributeValues::F64(v) => {
                        let mut b = [0u8; 8];
                        b.copy_from_slice(value);
                        v.push(f64::from_le_bytes(b))
                    }
                }
            }
        }
    }
    Ok(PointCloud {
        positions,
        colors,
        attributes,
        crs,
    })
}

/// Reads only the positions (and the CRS) of a LAS or LAZ file, what gridding needs: a LAZ file
/// of a layered point format (6 to 10, what [`write_las`] writes) decompresses its x, y and z
/// layers alone, skipping colours and extra bytes (several times less work than [`read_las`]).
/// The returned cloud has no colours and no attributes.
pub fn read_las_positions(path: &Path) -> Result<PointCloud, IoError> {
    let las_err = |e: las::Error| IoError::invalid(path, format!("cannot read LAS: {e}"));
    let mut reader = Reader::from_path(path).map_err(las_err)?;
    let header = reader.header().clone();
    let format = header.point_format();
    let positions = match header.laz_vlr() {
        Ok(vlr) if format.is_extended && format.is_compressed => {
            drop(reader);
            layered_laz_positions(path, &header, vlr)?
        }
        // Uncompressed, or point-wise compression (formats 0 to 5): nothing to skip.
        _ => positions_of(&reader.read_all().map_err(las_err)?).collect(),
    };
    Ok(PointCloud {
        positions,
        colors: None,
        attributes: Vec::new(),
        crs: crs_of(&header),
    })
}

/// The positions of a layered LAZ file, its x, y and z layers alone decompressed. The chunks
/// decompress in parallel, each into a record buffer of the worker that takes it, turned into
/// positions while it is in cache: no buffer of every record is made (for a cloud of 600,000
/// points that buffer and its page faults cost as much as the conversion and half as much as
/// the decoding). Before positions are allocated, the items must be the point format's own,
/// the header's point count the chunk table's, and every chunk's bytes in the file. The
/// compressed bytes are read a group of chunks at a time (a dense cloud's LAZ file is about 0.8
/// of the positions it holds: reading it whole would nearly double the peak).
fn layered_laz_positions(
    path: &Path,
    header: &las::Header,
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
    let record_len = layered_record_len(path, header, &vlr)?;
    source
        .seek(SeekFrom::Start(u64::from(raw.offset_to_point_data)))
        .map_err(io_err)?;
    let mut chunks = laz::laszip::ChunkTable::read_from(&mut source, &vlr)
        .map_err(laz_err)?
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
        decoding
            .decode_group(&compressed, group, &mut positions[start..])
            .map_err(laz_err)?;
    }
    Ok(positions)
}

/// The length of the file's layered point records, after checking that its LAZ items are the
/// point format's own. The decoder lays out each item at its own size, whatever the file
/// states: items other than the point format's own would be misread. (las derived the format's
/// extra bytes from the header's record length, so the expected items add up to it.)
fn layered_record_len(
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
            format!("its LAZ items do not make the header's {record_len}-byte layered records"),
        ));
    }
    Ok(record_len)
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
    let listed: u64 = chunks.iter().map(|c| c.point_count).sum();
    if listed != point_count {
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

/// The positions of decompressed records, from their x, y and z columns.
fn positions_of(data: &PointData) -> impl Iterator<Item = [f64; 3]> + '_ {
    data.x()
        .zip(data.y())
        .zip(data.z())
        .map(|((x, y), z)| [x, y, z])
}

/// The CRS a LAS header names: an EPSG code found in its WKT, else local.
fn crs_of(header: &las::Header) -> Crs {
    header
        .get_wkt_crs_bytes()
        .and_then(|wkt| epsg_of_wkt(&String::from_utf8_lossy(wkt)))
        .map(Crs::Epsg)
        .unwrap_or(Crs::Local)
}

/// The EPSG code of the outermost object of a WKT 1 definition (its last `AUTHORITY["EPSG",…]`).
fn epsg_of_wkt(wkt: &str) -> Option<u16> {
    let idx = wkt.rfind("AUTHORITY[\"EPSG\",")?;
    let rest = &wkt[idx + "AUTHORITY[\"EPSG\",".len()..];
    let code: String = rest
        .trim_start_matches('"')
        .chars()
        .take_while(|c| c.is_ascii_digit())
        .collect();
    code.parse().ok()
}
