//! A tiled TIFF writer in the cloud-optimised layout GIS users expect (what GDAL's COG driver and
//! OpenDroneMap write): 256 × 256 tiles, Deflate with a predictor, internal overviews as
//! reduced-resolution IFDs down to one tile, every IFD at the start of the file, then the tile
//! data from the smallest overview to the full resolution, tile offsets ascending in each IFD.
//! The `tiff` crate's encoder writes strips only, hence this module.
//!
//! [`TiledWriter`] takes the pixels a band of rows at a time, so an orthomosaic larger than
//! memory is written with one band per level in memory: each band's tiles are compressed as it
//! arrives and spooled (to a file beside the output, or to memory), its 2 × 2 averages feed the
//! next overview, and [`TiledWriter::finish`] writes the IFDs, then copies the tiles from the
//! spool in the file's order. A file whose offsets do not fit 32 bits is written as BigTIFF
//! (what GDAL does with `BIGTIFF=IF_SAFER`); [`Flavour::BigTiff`] asks for it always.

use std::io::{Read, Seek, SeekFrom, Write};

use flate2::Compression;
use flate2::write::ZlibEncoder;
use rayon::prelude::*;

/// Tile edge in pixels.
pub const TILE: usize = 256;

const SHORT: u16 = 3;
const LONG: u16 = 4;
const DOUBLE: u16 = 12;
const ASCII: u16 = 2;
const LONG8: u16 = 16;

/// One IFD entry with its value bytes (little-endian).
#[derive(Debug, Clone)]
pub struct Entry {
    tag: u16,
    kind: u16,
    count: u32,
    bytes: Vec<u8>,
}

impl Entry {
    /// SHORT values.
    pub fn shorts(tag: u16, values: &[u16]) -> Entry {
        Entry {
            tag,
            kind: SHORT,
            count: values.len() as u32,
            bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    /// LONG values.
    pub fn longs(tag: u16, values: &[u32]) -> Entry {
        Entry {
            tag,
            kind: LONG,
            count: values.len() as u32,
            bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    /// LONG8 values (BigTIFF's 64-bit offsets).
    fn long8s(tag: u16, values: &[u64]) -> Entry {
        Entry {
            tag,
            kind: LONG8,
            count: values.len() as u32,
            bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    /// DOUBLE values.
    pub fn doubles(tag: u16, values: &[f64]) -> Entry {
        Entry {
            tag,
            kind: DOUBLE,
            count: values.len() as u32,
            bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
    /// A NUL-terminated ASCII string.
    pub fn ascii(tag: u16, text: &str) -> Entry {
        let mut bytes = text.as_bytes().to_vec();
        bytes.push(0);
        Entry {
            tag,
            kind: ASCII,
            count: bytes.len() as u32,
            bytes,
        }
    }
}

/// What the pixels are: whole rows, row-major.
pub enum Pixels<'a> {
    /// One float32 band; `nodata` (and NaN) cells are left out of overview averages.
    F32 {
        /// Row-major values.
        data: &'a [f32],
        /// The declared nodata value.
        nodata: Option<f32>,
    },
    /// 8-bit grey (1 band), RGB (3) or RGBA (4, band 4 unassociated alpha), interleaved.
    U8 {
        /// Row-major interleaved samples.
        data: &'a [u8],
        /// 1, 3 or 4.
        bands: usize,
    },
}

impl Pixels<'_> {
    /// The sample layout of these pixels.
    pub fn format(&self) -> SampleFormat {
        match self {
            Pixels::F32 { nodata, .. } => SampleFormat::F32 { nodata: *nodata },
            Pixels::U8 { bands, .. } => SampleFormat::U8 { bands: *bands },
        }
    }

    /// Samples held.
    fn len(&self) -> usize {
        match self {
            Pixels::F32 { data, .. } => data.len(),
            Pixels::U8 { data, .. } => data.len(),
        }
    }

    /// The samples in `range`, same format.
    fn slice(&self, range: std::ops::Range<usize>) -> Pixels<'_> {
        match self {
            Pixels::F32 { data, nodata } => Pixels::F32 {
                data: &data[range],
                nodata: *nodata,
            },
            Pixels::U8 { data, bands } => Pixels::U8 {
                data: &data[range],
                bands: *bands,
            },
        }
    }

    /// An owned copy.
    fn to_rows(&self) -> Rows {
        match self {
            Pixels::F32 { data, .. } => Rows::F32(data.to_vec()),
            Pixels::U8 { data, .. } => Rows::U8(data.to_vec()),
        }
    }

    /// The 2 × 2 averages of these `w` × `h` pixels (nodata and transparent cells left out).
    fn halved(&self, w: usize, h: usize) -> Rows {
        match self {
            Pixels::F32 { data, nodata } => Rows::F32(halve_f32(data, w, h, *nodata)),
            Pixels::U8 { data, bands } => Rows::U8(halve_u8(data, w, h, *bands)),
        }
    }
}

/// The sample layout of a file, without its pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SampleFormat {
    /// One float32 band and its nodata value.
    F32 {
        /// The declared nodata value.
        nodata: Option<f32>,
    },
    /// 1, 3 or 4 interleaved u8 bands.
    U8 {
        /// 1, 3 or 4.
        bands: usize,
    },
}

impl SampleFormat {
    fn bands(&self) -> usize {
        match self {
            SampleFormat::F32 { .. } => 1,
            SampleFormat::U8 { bands } => *bands,
        }
    }
}

/// Classic TIFF or BigTIFF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Flavour {
    /// Classic TIFF when every offset fits 32 bits (files up to 4 GiB), BigTIFF beyond.
    #[default]
    Auto,
    /// BigTIFF whatever the size.
    BigTiff,
}

/// Why the tiled file could not be written.
#[derive(Debug)]
pub enum TiledError {
    /// Writing or spooling failed.
    Io(std::io::Error),
    /// Rows that do not fit the file: another sample format, a partial row, more rows than
    /// the height, or fewer at [`TiledWriter::finish`].
    Rows(String),
}

/// Rows of one resolution level waiting to make a row of tiles, owned.
enum Rows {
    F32(Vec<f32>),
    U8(Vec<u8>),
}

impl Rows {
    fn empty(format: SampleFormat) -> Rows {
        match format {
            SampleFormat::F32 { .. } => Rows::F32(Vec::new()),
            SampleFormat::U8 { .. } => Rows::U8(Vec::new()),
        }
    }

    fn len(&self) -> usize {
        match self {
            Rows::F32(v) => v.len(),
            Rows::U8(v) => v.len(),
        }
    }

    fn append(&mut self, more: Rows) {
        match (self, more) {
            (Rows::F32(a), Rows::F32(b)) if a.is_empty() => *a = b,
            (Rows::F32(a), Rows::F32(b)) => a.extend_from_slice(&b),
            (Rows::U8(a), Rows::U8(b)) if a.is_empty() => *a = b,
            (Rows::U8(a), Rows::U8(b)) => a.extend_from_slice(&b),
            // Invariant: `push_rows` refuses pixels of another format than the writer's, and
            // every level's rows are made of the writer's one format.
            _ => unreachable!("one level holds one sample type"),
        }
    }

    /// The first `samples` samples, as pixels of `format`.
    fn head(&self, samples: usize, format: SampleFormat) -> Pixels<'_> {
        match (self, format) {
            (Rows::F32(v), SampleFormat::F32 { nodata }) => Pixels::F32 {
                data: &v[..samples],
                nodata,
            },
            (Rows::U8(v), SampleFormat::U8 { bands }) => Pixels::U8 {
                data: &v[..samples],
                bands,
            },
            // Invariant: the rows and `format` are both the writer's one format.
            _ => unreachable!("one level holds one sample type"),
        }
    }

    /// Removes the first `samples` samples.
    fn drain_front(&mut self, samples: usize) {
        match self {
            Rows::F32(v) => drop(v.drain(..samples)),
            Rows::U8(v) => drop(v.drain(..samples)),
        }
    }
}

/// One resolution level as it fills.
struct LevelState {
    width: usize,
    height: usize,
    /// Rows received so far (made into tiles or pending).
    received: usize,
    pending: Rows,
    /// Each tile's place in the spool (offset, length), row-major.
    tiles: Vec<(u64, u32)>,
}

/// A tiled TIFF written a band of rows at a time; see the module documentation.
pub struct TiledWriter<S: Read + Write + Seek> {
    format: SampleFormat,
    levels: Vec<LevelState>,
    spool: S,
    spool_len: u64,
}

impl<S: Read + Write + Seek> TiledWriter<S> {
    /// A writer of a `width` × `height` raster whose tiles are spooled to `spool` (written from
    /// its start; a file beside the output for rasters larger than memory, a
    /// `Cursor<Vec<u8>>` otherwise).
    pub fn new(width: usize, height: usize, format: SampleFormat, spool: S) -> Self {
        let mut levels = vec![(width, height)];
        while let Some(&(w, h)) = levels.last() {
            if w <= TILE && h <= TILE {
                break;
            }
            levels.push((w.div_ceil(2), h.div_ceil(2)));
        }
        TiledWriter {
            format,
            levels: levels
                .into_iter()
                .map(|(width, height)| LevelState {
                    width,
                    height,
                    received: 0,
                    pending: Rows::empty(format),
                    tiles: Vec::new(),
                })
                .collect(),
            spool,
            spool_len: 0,
        }
    }

    /// Full-resolution rows received so far.
    pub fn rows_received(&self) -> usize {
        self.levels[0].received
    }

    /// Appends whole rows below those already given: tiles are made as soon as a band of
    /// [`TILE`] rows is complete, at every level.
    pub fn push_rows(&mut self, pixels: Pixels<'_>) -> Result<(), TiledError> {
        if pixels.format() != self.format {
            return Err(TiledError::Rows(format!(
                "{:?} rows given to a file of {:?}",
                pixels.format(),
                self.format
            )));
        }
        let row_len = self.levels[0].width * self.format.bands();
        let rows = pixels.len() / row_len.max(1);
        if pixels.len() % row_len.max(1) != 0
            || self.levels[0].received + rows > self.levels[0].height
        {
            return Err(TiledError::Rows(format!(
                "{} samples are not whole rows of {} below row {} of {}",
                pixels.len(),
                row_len,
                self.levels[0].received,
                self.levels[0].height
            )));
        }
        // At most a band of tiles at a time, so that what waits for its tiles stays under two
        // bands, however many rows come at once.
        let band = TILE * row_len;
        (0..pixels.len()).step_by(band).try_for_each(|start| {
            let end = (start + band).min(pixels.len());
            self.feed(pixels.slice(start..end).to_rows())
        })
    }

    /// Gives `rows` to the full-resolution level; every complete band of tiles there is
    /// compressed and spooled, and its 2 × 2 averages go down a level, and so on.
    fn feed(&mut self, rows: Rows) -> Result<(), TiledError> {
        let row_samples = self.format.bands();
        let n_levels = self.levels.len();
        let mut incoming = Some(rows);
        for k in 0..n_levels {
            let Some(rows) = incoming.take() else { break };
            let level = &mut self.levels[k];
            let row_len = level.width * row_samples;
            level.received += rows.len() / row_len;
            level.pending.append(rows);
            let mut halves = Rows::empty(self.format);
            loop {
                let pending_rows = level.pending.len() / row_len;
                let last = level.received == level.height;
                if pending_rows == 0 || (pending_rows < TILE && !last) {
                    break;
                }
                let n = pending_rows.min(TILE);
                let band = level.pending.head(n * row_len, self.format);
                for tile in compress_band(&band, level.width, n)? {
                    self.spool.write_all(&tile).map_err(TiledError::Io)?;
                    level.tiles.push((self.spool_len, tile.len() as u32));
                    self.spool_len += tile.len() as u64;
                }
                if k + 1 < n_levels {
                    halves.append(band.halved(level.width, n));
                }
                level.pending.drain_front(n * row_len);
            }
            if halves.len() > 0 {
                incoming = Some(halves);
            }
        }
        Ok(())
    }

    /// Writes the file to `out`: header, IFDs (`georef` entries — GeoTIFF tags, nodata — in the
    /// full-resolution one, `nodata` also in the overviews'), their values, then the tiles from
    /// the smallest overview up, copied from the spool.
    pub fn finish(
        mut self,
        out: &mut impl Write,
        georef: &[Entry],
        nodata: Option<&Entry>,
        flavour: Flavour,
    ) -> Result<(), TiledError> {
        let full = &self.levels[0];
        if full.received != full.height {
            return Err(TiledError::Rows(format!(
                "{} of {} rows given",
                full.received, full.height
            )));
        }
        let mut ifds = level_ifds(&self.levels, self.format, georef, nodata);
        let (layout, big) = lay_out(&mut ifds, &self.levels, flavour);

        // Serialise, following the layout.
        let mut out = Positioned { out, at: 0 };
        write_header_and_ifds(&mut out, &ifds, &layout, big)?;
        let inline = if big { 8 } else { 4 };
        for (k, e) in ifds.iter().enumerate() {
            for (entry, &at) in e.iter().zip(&layout.values[k]) {
                if entry.bytes.len() > inline {
                    out.pad_to(at)?;
                    out.put(&entry.bytes)?;
                }
            }
        }
        let mut buffer = Vec::new();
        for k in (0..self.levels.len()).rev() {
            for (&(from, len), &at) in self.levels[k].tiles.iter().zip(&layout.tiles[k]) {
                debug_assert_eq!(out.at, at);
                buffer.resize(len as usize, 0);
                self.spool
                    .seek(SeekFrom::Start(from))
                    .and_then(|_| self.spool.read_exact(&mut buffer))
                    .map_err(TiledError::Io)?;
                out.put(&buffer)?;
            }
        }
        Ok(())
    }
}

/// Each level's IFD, its entries sorted by tag (`georef` in the full-resolution one, `nodata`
/// in all). Its TileOffsets (324) holds one zero per tile: their count, not their values,
/// decides the layout, which then gives them their values.
fn level_ifds(
    levels: &[LevelState],
    format: SampleFormat,
    georef: &[Entry],
    nodata: Option<&Entry>,
) -> Vec<Vec<Entry>> {
    let (bands, float) = match format {
        SampleFormat::F32 { .. } => (1, true),
        SampleFormat::U8 { bands } => (bands, false),
    };
    let mut ifds: Vec<Vec<Entry>> = Vec::new();
    for (k, level) in levels.iter().enumerate() {
        let n_tiles = level.tiles.len();
        let mut e = vec![
            Entry::longs(254, &[if k == 0 { 0 } else { 1 }]),
            Entry::longs(256, &[level.width as u32]),
            Entry::longs(257, &[level.height as u32]),
            Entry::shorts(258, &vec![if float { 32 } else { 8 }; bands]),
            Entry::shorts(259, &[8]),
            Entry::shorts(262, &[if bands >= 3 { 2 } else { 1 }]),
            Entry::shorts(277, &[bands as u16]),
            Entry::shorts(284, &[1]),
            Entry::shorts(317, &[if float { 3 } else { 2 }]),
            Entry::shorts(322, &[TILE as u16]),
            Entry::shorts(323, &[TILE as u16]),
            Entry::longs(324, &vec![0; n_tiles]),
            Entry::longs(325, &level.tiles.iter().map(|t| t.1).collect::<Vec<_>>()),
            Entry::shorts(339, &vec![if float { 3 } else { 1 }; bands]),
        ];
        if bands == 4 {
            e.push(Entry::shorts(338, &[2]));
        }
        if k == 0 {
            e.extend(georef.iter().cloned());
        }
        if let Some(nd) = nodata {
            e.push(nd.clone());
        }
        e.sort_by_key(|e| e.tag);
        ifds.push(e);
    }
    ifds
}

/// The layout of the file, and whether it is a BigTIFF (asked for, or a classic TIFF would pass
/// 4 GiB); the IFDs' TileOffsets are given their positions (64-bit in a BigTIFF).
fn lay_out(ifds: &mut [Vec<Entry>], levels: &[LevelState], flavour: Flavour) -> (Layout, bool) {
    let classic = Layout::of(ifds, levels, false);
    let big = flavour == Flavour::BigTiff || classic.end > u32::MAX as u64;
    let layout = if big {
        // The offsets become 64-bit values (the entry keeps its count).
        for (k, e) in ifds.iter_mut().enumerate() {
            if let Some(entry) = e.iter_mut().find(|e| e.tag == 324) {
                *entry = Entry::long8s(324, &vec![0; levels[k].tiles.len()]);
            }
        }
        Layout::of(ifds, levels, true)
    } else {
        classic
    };
    for (k, e) in ifds.iter_mut().enumerate() {
        // The entry was made with one zero per tile; same size, now the positions.
        if let Some(entry) = e.iter_mut().find(|e| e.tag == 324) {
            *entry = if big {
                Entry::long8s(324, &layout.tiles[k])
            } else {
                let offsets: Vec<u32> = layout.tiles[k].iter().map(|&p| p as u32).collect();
                Entry::longs(324, &offsets)
            };
        }
    }
    (layout, big)
}

/// Writes an offset: 8 bytes in a BigTIFF, else 4.
fn put_offset<W: Write>(
    out: &mut Positioned<'_, W>,
    value: u64,
    big: bool,
) -> Result<(), TiledError> {
    if big {
        out.put(&value.to_le_bytes())
    } else {
        out.put(&(value as u32).to_le_bytes())
    }
}

/// Writes the header and every IFD (entries with inline values or the positions of their
/// values, then the next IFD's position) as `layout` places them.
fn write_header_and_ifds<W: Write>(
    out: &mut Positioned<'_, W>,
    ifds: &[Vec<Entry>],
    layout: &Layout,
    big: bool,
) -> Result<(), TiledError> {
    out.put(b"II")?;
    if big {
        out.put(&43u16.to_le_bytes())?;
        out.put(&8u16.to_le_bytes())?;
        out.put(&0u16.to_le_bytes())?;
    } else {
        out.put(&42u16.to_le_bytes())?;
    }
    put_offset(out, layout.ifds[0], big)?;
    let inline = if big { 8 } else { 4 };
    for (k, e) in ifds.iter().enumerate() {
        if big {
            out.put(&(e.len() as u64).to_le_bytes())?;
        } else {
            out.put(&(e.len() as u16).to_le_bytes())?;
        }
        for (entry, &at) in e.iter().zip(&layout.values[k]) {
            out.put(&entry.tag.to_le_bytes())?;
            out.put(&entry.kind.to_le_bytes())?;
            if big {
                out.put(&(entry.count as u64).to_le_bytes())?;
            } else {
                out.put(&entry.count.to_le_bytes())?;
            }
            if entry.bytes.len() > inline {
                put_offset(out, at, big)?;
            } else {
                let mut value = [0u8; 8];
                value[..entry.bytes.len()].copy_from_slice(&entry.bytes);
                out.put(&value[..inline])?;
            }
        }
        put_offset(out, layout.ifds.get(k + 1).copied().unwrap_or(0), big)?;
    }
    Ok(())
}

/// Where everything goes in the file.
struct Layout {
    /// Each IFD's position.
    ifds: Vec<u64>,
    /// Each IFD entry's out-of-line value position (0 for inline values).
    values: Vec<Vec<u64>>,
    /// Each level's tiles' positions.
    tiles: Vec<Vec<u64>>,
    /// The file's size.
    end: u64,
}

impl Layout {
    /// Header, IFDs, their out-of-line values, tile data smallest level first.
    fn of(ifds: &[Vec<Entry>], levels: &[LevelState], big: bool) -> Layout {
        let (header, count, entry, next, inline) = if big {
            (16, 8, 20, 8, 8)
        } else {
            (8, 2, 12, 4, 4)
        };
        let mut pos: u64 = header;
        let mut ifd_pos = Vec::with_capacity(ifds.len());
        for e in ifds {
            ifd_pos.push(pos);
            pos += count + entry * e.len() as u64 + next;
        }
        let mut values = Vec::with_capacity(ifds.len());
        for e in ifds {
            let mut v = Vec::with_capacity(e.len());
            for entry in e {
                if entry.bytes.len() > inline {
                    pos += pos % 2;
                    v.push(pos);
                    pos += entry.bytes.len() as u64;
                } else {
                    v.push(0);
                }
            }
            values.push(v);
        }
        let mut tiles: Vec<Vec<u64>> = vec![Vec::new(); levels.len()];
        for k in (0..levels.len()).rev() {
            for &(_, len) in &levels[k].tiles {
                tiles[k].push(pos);
                pos += len as u64;
            }
        }
        Layout {
            ifds: ifd_pos,
            values,
            tiles,
            end: pos,
        }
    }
}

/// Writes a whole raster as a tiled TIFF with overviews (tiles spooled in memory); see
/// [`TiledWriter::finish`] for `georef` and `nodata`.
pub fn write_tiled(
    out: &mut impl Write,
    width: usize,
    height: usize,
    pixels: Pixels<'_>,
    georef: &[Entry],
    nodata: Option<&Entry>,
) -> Result<(), TiledError> {
    let mut writer = TiledWriter::new(
        width,
        height,
        pixels.format(),
        std::io::Cursor::new(Vec::new()),
    );
    writer.push_rows(pixels)?;
    writer.finish(out, georef, nodata, Flavour::Auto)
}

/// A writer that knows how many bytes it has written: its position in the file.
struct Positioned<'a, W: Write> {
    out: &'a mut W,
    at: u64,
}

impl<W: Write> Positioned<'_, W> {
    fn put(&mut self, bytes: &[u8]) -> Result<(), TiledError> {
        self.out.write_all(bytes).map_err(TiledError::Io)?;
        self.at += bytes.len() as u64;
        Ok(())
    }

    /// Zero bytes up to position `at` (the word alignment of out-of-line values).
    fn pad_to(&mut self, at: u64) -> Result<(), TiledError> {
        while self.at < at {
            self.put(&[0])?;
        }
        Ok(())
    }
}

/// Deflate's level: 4 rather than zlib's default 6. After the predictor, what is left in a DEM
/// or an ortho is mostly sensor and matching noise, which longer match searches barely shrink:
/// on the synthetic orchard (a 480 × 360 DEM, its spread and counts; a 4-band ortho) level 4
/// wrote 25–36 % faster than 6 for files 0.7–2 % larger (level 1: 13–60 % larger).
const DEFLATE_LEVEL: u32 = 4;

/// Cuts a band of `h` ≤ [`TILE`] rows into tiles (edge tiles padded with zeros), applies the
/// predictor and compresses each, in parallel.
fn compress_band(band: &Pixels<'_>, w: usize, h: usize) -> Result<Vec<Vec<u8>>, TiledError> {
    let bands = band.format().bands();
    let across = w.div_ceil(TILE);
    (0..across)
        .into_par_iter()
        .map(|tc| {
            let mut raw = Vec::with_capacity(TILE * TILE * bands * 4);
            for y in 0..TILE {
                let row_start = raw.len();
                for c in 0..TILE {
                    let x = tc * TILE + c;
                    let inside = x < w && y < h;
                    match band {
                        Pixels::F32 { data: v, .. } => {
                            let value = if inside { v[y * w + x] } else { 0.0 };
                            raw.extend_from_slice(&value.to_le_bytes());
                        }
                        Pixels::U8 { data: v, .. } => {
                            for b in 0..bands {
                                raw.push(if inside {
                                    v[(y * w + x) * bands + b]
                                } else {
                                    0
                                });
                            }
                        }
                    }
                }
                let row = &mut raw[row_start..];
                match band {
                    Pixels::F32 { .. } => float_predictor(row),
                    Pixels::U8 { .. } => {
                        for i in (bands..row.len()).rev() {
                            row[i] = row[i].wrapping_sub(row[i - bands]);
                        }
                    }
                }
            }
            let mut z = ZlibEncoder::new(Vec::new(), Compression::new(DEFLATE_LEVEL));
            z.write_all(&raw)?;
            z.finish()
        })
        .collect::<std::io::Result<_>>()
        .map_err(TiledError::Io)
}

/// The floating-point predictor (TIFF predictor 3) on one row of little-endian f32: bytes
/// regrouped by significance (most significant plane first), then differenced.
fn float_predictor(row: &mut [u8]) {
    let n = row.len() / 4;
    let tmp = row.to_vec();
    for i in 0..n {
        for b in 0..4 {
            row[(4 - b - 1) * n + i] = tmp[4 * i + b];
        }
    }
    for i in (1..row.len()).rev() {
        row[i] = row[i].wrapping_sub(row[i - 1]);
    }
}

fn halve_f32(v: &[f32], w: usize, h: usize, nodata: Option<f32>) -> Vec<f32> {
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let invalid = |x: f32| x.is_nan() || Some(x) == nodata;
    let mut out = vec![nodata.unwrap_or(f32::NAN); w2 * h2];
    for r in 0..h2 {
        for c in 0..w2 {
            let (mut sum, mut n) = (0.0f64, 0u32);
            for (dr, dc) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let (y, x) = (2 * r + dr, 2 * c + dc);
                if y < h && x < w && !invalid(v[y * w + x]) {
                    sum += v[y * w + x] as f64;
                    n += 1;
                }
            }
            if n > 0 {
                out[r * w2 + c] = (sum / n as f64) as f32;
            }
        }
    }
    out
}

fn halve_u8(v: &[u8], w: usize, h: usize, bands: usize) -> Vec<u8> {
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let colours = bands.min(3);
    let mut out = vec![0u8; w2 * h2 * bands];
    for r in 0..h2 {
        for c in 0..w2 {
            let mut sum = [0u32; 4];
            let mut weight = 0u32;
            let mut n = 0u32;
            for (dr, dc) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let (y, x) = (2 * r + dr, 2 * c + dc);
                if y >= h || x >= w {
                    continue;
                }
                let px = &v[(y * w + x) * bands..(y * w + x + 1) * bands];
                // Colours weighted by alpha, so transparent pixels do not darken the edges.
                let a = if bands == 4 { px[3] as u32 } else { 1 };
                for b in 0..colours {
                    sum[b] += a * px[b] as u32;
                }
                if bands == 4 {
                    sum[3] += px[3] as u32;
                }
                weight += a;
                n += 1;
            }
            let o = &mut out[(r * w2 + c) * bands..(r * w2 + c + 1) * bands];
            for b in 0..colours {
                if let Some(v) = (sum[b] + weight / 2).checked_div(weight) {
                    o[b] = v as u8;
                }
            }
            if bands == 4
                && let Some(v) = (sum[3] + n / 2).checked_div(n)
            {
                o[3] = v as u8;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use tiff::decoder::{Decoder, DecodingResult};

    /// Every level of a file, decoded by the `tiff` crate (an independent reader).
    fn decode_levels(bytes: &[u8]) -> Vec<(u32, u32, DecodingResult)> {
        let mut d = Decoder::new(std::io::Cursor::new(bytes)).unwrap();
        let mut levels = Vec::new();
        loop {
            let (w, h) = d.dimensions().unwrap();
            levels.push((w, h, d.read_image().unwrap()));
            if !d.more_images() {
                break;
            }
            d.next_image().unwrap();
        }
        levels
    }

    #[test]
    fn multi_tile_floats_with_nodata_round_trip_and_get_overviews() {
        let (w, h) = (700, 300);
        let mut data: Vec<f32> = (0..w * h)
            .map(|i| ((i % w) as f32 * 0.37 - (i / w) as f32 * 1.1).sin() * 100.0 + 5e3)
            .collect();
        data[3] = -32767.0;
        data[w + 1] = -32767.0;
        data[w] = -32767.0;
        data[4] = -32767.0;
        data[1] = f32::NAN;
        let mut bytes = Vec::new();
        let nd = Entry::ascii(42113, "-32767");
        write_tiled(
            &mut bytes,
            w,
            h,
            Pixels::F32 {
                data: &data,
                nodata: Some(-32767.0),
            },
            &[],
            Some(&nd),
        )
        .unwrap();
        let levels = decode_levels(&bytes);
        // 700 × 300 → 350 × 150 → 175 × 75, the last one fits one tile.
        assert_eq!(levels.len(), 3);
        assert_eq!((levels[2].0, levels[2].1), (175, 75));
        let DecodingResult::F32(full) = &levels[0].2 else {
            panic!("not f32")
        };
        assert_eq!(full.len(), w * h);
        for (a, b) in full.iter().zip(&data) {
            assert!(a == b || (a.is_nan() && b.is_nan()));
        }
        assert_eq!((levels[1].0, levels[1].1), (350, 150));
        let DecodingResult::F32(half) = &levels[1].2 else {
            panic!("not f32")
        };
        // Cell (1, 0) of the overview averages the valid ones of (2..4, 0..2): 2 of 4 are nodata.
        let expect = (data[2] as f64 + data[w + 2] as f64 + data[w + 3] as f64) / 3.0;
        assert!(
            (half[1] as f64 - expect).abs() < 1e-2,
            "{} {expect}",
            half[1]
        );
        // Cell (0, 0): only (0, 0) is valid (1 is NaN, w and w+1 are nodata).
        assert_eq!(half[0], data[0]);
        // Compressed.
        assert!(bytes.len() < w * h * 4);
    }

    #[test]
    fn rgba_tiles_round_trip_and_overviews_ignore_transparent_pixels() {
        let (w, h) = (520, 260);
        let mut data = vec![0u8; w * h * 4];
        for (i, px) in data.chunks_mut(4).enumerate() {
            let (x, y) = (i % w, i / w);
            px[0] = (x % 251) as u8;
            px[1] = (y % 241) as u8;
            px[2] = ((x * y) % 256) as u8;
            px[3] = if x < 2 && y < 2 && (x + y) % 2 == 1 {
                0
            } else {
                255
            };
        }
        let mut bytes = Vec::new();
        write_tiled(
            &mut bytes,
            w,
            h,
            Pixels::U8 {
                data: &data,
                bands: 4,
            },
            &[],
            None,
        )
        .unwrap();
        let levels = decode_levels(&bytes);
        // 520 × 260 → 260 × 130 → 130 × 65.
        assert_eq!(levels.len(), 3);
        let DecodingResult::U8(full) = &levels[0].2 else {
            panic!("not u8")
        };
        assert_eq!(full, &data);
        let DecodingResult::U8(half) = &levels[1].2 else {
            panic!("not u8")
        };
        // Pixel (0, 0) of the overview: (0,0) and (1,1) opaque, the others transparent.
        let r = (data[0] as u32 + data[(w + 1) * 4] as u32).div_ceil(2) as u8;
        assert!((half[0] as i32 - r as i32).abs() <= 1);
        assert_eq!(half[3], 128);
    }

    /// A float raster over several rows of tiles at two levels, with nodata.
    fn floats(w: usize, h: usize) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                if i % 89 == 0 {
                    -32767.0
                } else {
                    ((i % w) as f32 * 0.021).cos() * 40.0 + (i / w) as f32 * 0.3
                }
            })
            .collect()
    }

    fn rgba(w: usize, h: usize) -> Vec<u8> {
        (0..w * h * 4)
            .map(|i| {
                if i % 4 == 3 {
                    ((i / 4) % 3 * 127) as u8
                } else {
                    (i * 7 % 251) as u8
                }
            })
            .collect()
    }

    /// Streams `pixels` in bands of `rows` rows (the last one shorter) into a file.
    fn streamed(w: usize, h: usize, pixels: Pixels<'_>, rows: usize, flavour: Flavour) -> Vec<u8> {
        let mut writer = TiledWriter::new(w, h, pixels.format(), std::io::Cursor::new(Vec::new()));
        let bands = pixels.format().bands();
        for r in (0..h).step_by(rows) {
            let range = r * w * bands..(r + rows).min(h) * w * bands;
            writer.push_rows(pixels.slice(range)).unwrap();
        }
        let mut out = Vec::new();
        writer.finish(&mut out, &[], None, flavour).unwrap();
        out
    }

    #[test]
    fn rows_streamed_in_any_bands_make_the_same_file_as_the_whole_raster() {
        // 700 × 1100: five rows of tiles at full resolution, three at the first overview.
        let (w, h) = (700, 1100);
        let data = floats(w, h);
        let f32_pixels = || Pixels::F32 {
            data: &data,
            nodata: Some(-32767.0),
        };
        let mut whole = Vec::new();
        write_tiled(&mut whole, w, h, f32_pixels(), &[], None).unwrap();
        for rows in [1, 37, 256, 300, h] {
            assert!(
                streamed(w, h, f32_pixels(), rows, Flavour::Auto) == whole,
                "float rows in bands of {rows}"
            );
        }
        let colours = rgba(w, h);
        let u8_pixels = || Pixels::U8 {
            data: &colours,
            bands: 4,
        };
        let mut whole = Vec::new();
        write_tiled(&mut whole, w, h, u8_pixels(), &[], None).unwrap();
        for rows in [3, 255, 513] {
            assert!(
                streamed(w, h, u8_pixels(), rows, Flavour::Auto) == whole,
                "rgba rows in bands of {rows}"
            );
        }
    }

    #[test]
    fn big_tiff_holds_the_same_levels_as_classic_tiff() {
        let (w, h) = (600, 520);
        let data = floats(w, h);
        let pixels = || Pixels::F32 {
            data: &data,
            nodata: Some(-32767.0),
        };
        let classic = streamed(w, h, pixels(), 100, Flavour::Auto);
        let big = streamed(w, h, pixels(), 100, Flavour::BigTiff);
        assert_eq!(&classic[2..4], &42u16.to_le_bytes());
        assert_eq!(&big[2..4], &43u16.to_le_bytes());
        let (a, b) = (decode_levels(&classic), decode_levels(&big));
        assert_eq!(a.len(), 3);
        assert_eq!(a.len(), b.len());
        for ((wa, ha, va), (wb, hb, vb)) in a.iter().zip(&b) {
            assert_eq!((wa, ha), (wb, hb));
            let (DecodingResult::F32(va), DecodingResult::F32(vb)) = (va, vb) else {
                panic!("not f32")
            };
            assert!(va == vb, "level {wa} × {ha} differs");
        }
        let DecodingResult::F32(full) = &b[0].2 else {
            panic!("not f32")
        };
        assert!(full == &data);
    }

    #[test]
    fn rows_that_do_not_fit_the_file_are_refused() {
        let spool = || std::io::Cursor::new(Vec::new());
        let format = SampleFormat::U8 { bands: 3 };
        let mut writer = TiledWriter::new(10, 4, format, spool());
        let wrong_type = writer.push_rows(Pixels::F32 {
            data: &[0.0; 10],
            nodata: None,
        });
        assert!(matches!(wrong_type, Err(TiledError::Rows(m)) if m.contains("rows given to")));
        let partial = writer.push_rows(Pixels::U8 {
            data: &[0; 29],
            bands: 3,
        });
        assert!(matches!(partial, Err(TiledError::Rows(m)) if m.contains("not whole rows")));
        writer
            .push_rows(Pixels::U8 {
                data: &[0; 90],
                bands: 3,
            })
            .unwrap();
        assert_eq!(writer.rows_received(), 3);
        let too_many = writer.push_rows(Pixels::U8 {
            data: &[0; 60],
            bands: 3,
        });
        assert!(matches!(too_many, Err(TiledError::Rows(_))));
        let early = writer.finish(&mut Vec::new(), &[], None, Flavour::Auto);
        assert!(matches!(early, Err(TiledError::Rows(m)) if m == "3 of 4 rows given"));
    }
}
