//! Point clouds in LAS 1.4 / LAZ: positions in f64 through the file's offset and scale, optional RGB,
//! named extra attributes (the LAS "extra bytes"), and the CRS as a WKT record.
//!
//! LAS stores integers scaled and offset; the writer takes the scale (default 1 mm) and puts the
//! offset at the cloud's minimum corner rounded to the metre, so UTM-sized coordinates keep full
//! precision. The format (LAS or LAZ) follows the file extension.

use std::io::BufReader;
use std::path::Path;

use las::{
    Builder, Color, Point, PointData, Reader, Transform, Vector, Version, Vlr, Writer,
    point::Format,
};

use crate::coords::Crs;
use crate::decoder_guard;
use crate::las_checks::{self, CheckedHeader};
use crate::las_sink::FailOnce;
use crate::laz_positions;
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
    // LAZ when the file is named so (what `las` decides from a path, done here because the
    // writer is given a sink, not a path).
    format.is_compressed = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
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
    let file = std::fs::File::create(tmp).map_err(|e| IoError::io(path, e))?;
    let sink = FailOnce::new(std::io::BufWriter::new(file));
    let mut writer = Writer::new(sink, header).map_err(las_err)?;
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
    let sink = writer.into_inner().map_err(las_err)?;
    // Durable before it is renamed over the target.
    sink.into_file()
        .and_then(|file| file.sync_all())
        .map_err(|e| IoError::io(path, e))
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
    let (mut reader, checked) = open_checked(path)?;
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
    let data = decoder_guard::catch_decoder_panic(path, "the LAZ decoder", || {
        reader.read_all().map_err(las_err)
    })?;
    // Column by column from the decompressed records: materialising a `las::Point` per record
    // allocates its extra bytes, which cost more than the decompression itself.
    let mut positions = Vec::with_capacity(data.len());
    positions.extend(positions_of(&data));
    check_positions_by_chunk(path, &checked, &header, &positions)?;
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
    let (mut reader, checked) = open_checked(path)?;
    let header = reader.header().clone();
    let format = header.point_format();
    let positions = match header.laz_vlr() {
        Ok(vlr) if format.is_extended && format.is_compressed => {
            drop(reader);
            laz_positions::layered_laz_positions(path, &header, &checked, vlr)?
        }
        // Uncompressed, or point-wise compression (formats 0 to 5): nothing to skip.
        _ => {
            let positions: Vec<[f64; 3]> = positions_of(&decoder_guard::catch_decoder_panic(
                path,
                "the LAZ decoder",
                || reader.read_all().map_err(las_err),
            )?)
            .collect();
            check_positions_by_chunk(path, &checked, &header, &positions)?;
            positions
        }
    };
    Ok(PointCloud {
        positions,
        colors: None,
        attributes: Vec::new(),
        crs: crs_of(&header),
    })
}

/// A reader of `path` once what the file claims has been checked against it
/// ([`las_checks`]): the header, and a LAZ file's chunk table and layer lengths.
fn open_checked(path: &Path) -> Result<(Reader, CheckedHeader), IoError> {
    let las_err = |e: las::Error| IoError::invalid(path, format!("cannot read LAS: {e}"));
    let checked = las_checks::check_header(path)?;
    if checked.compressed {
        // Before a reader is made: making one reads the chunk table.
        las_checks::check_chunk_table(path, &checked)?;
        let file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
        let header = las::Header::new(BufReader::new(file)).map_err(las_err)?;
        if let Ok(vlr) = header.laz_vlr() {
            // The items first: items other than the point format's own are misread (and the
            // decompressor asserts on records of another length), and would misplace every
            // length checked after.
            las_checks::record_len_of_items(path, &header, &vlr)?;
            las_checks::check_chunks(path, &checked, &vlr)?;
        }
    }
    let reader = Reader::from_path(path).map_err(las_err)?;
    Ok((reader, checked))
}

/// Checks every position against the header's bounds, chunk by chunk when the file is LAZ of
/// fixed-size chunks (so that the error names the chunk).
fn check_positions_by_chunk(
    path: &Path,
    checked: &CheckedHeader,
    header: &las::Header,
    positions: &[[f64; 3]],
) -> Result<(), IoError> {
    let chunk_size = header
        .laz_vlr()
        .ok()
        .filter(|v| !v.uses_variable_size_chunks() && v.chunk_size() > 0)
        .map(|v| v.chunk_size() as usize);
    match chunk_size {
        Some(size) => positions
            .chunks(size)
            .enumerate()
            .try_for_each(|(k, chunk)| {
                las_checks::check_positions(path, checked, chunk, (k * size) as u64, Some(k))
            }),
        None => las_checks::check_positions(path, checked, positions, 0, None),
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
