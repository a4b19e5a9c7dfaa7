//! A tiled TIFF writer in the cloud-optimised layout GIS users expect (what GDAL's COG driver and
//! OpenDroneMap write): 256 × 256 tiles, Deflate with a predictor, internal overviews as
//! reduced-resolution IFDs down to one tile, every IFD at the start of the file, then the tile
//! data from the smallest overview to the full resolution, tile offsets ascending in each IFD.
//! The `tiff` crate's encoder writes strips only, hence this module.
//!
//! Classic TIFF (32-bit offsets): a file over 4 GiB is refused with an error rather than
//! written as BigTIFF.

use std::io::Write;

use flate2::Compression;
use flate2::write::ZlibEncoder;
use rayon::prelude::*;

/// Tile edge in pixels.
pub const TILE: usize = 256;

const SHORT: u16 = 3;
const LONG: u16 = 4;
const DOUBLE: u16 = 12;
const ASCII: u16 = 2;

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

/// What the pixels are.
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

/// One resolution level, owned.
enum Level {
    F32(Vec<f32>),
    U8(Vec<u8>),
}

/// Why the tiled file could not be written.
#[derive(Debug)]
pub enum TiledError {
    /// Writing failed.
    Io(std::io::Error),
    /// The compressed file would exceed classic TIFF's 4 GiB.
    TooLarge(u64),
}

/// Writes a tiled TIFF with overviews; `georef` entries (GeoTIFF tags, nodata) go into the
/// full-resolution IFD, `nodata` also into the overviews'.
pub fn write_tiled(
    out: &mut impl Write,
    width: usize,
    height: usize,
    pixels: Pixels<'_>,
    georef: &[Entry],
    nodata: Option<&Entry>,
) -> Result<(), TiledError> {
    let (bands, float, nodata_value) = match &pixels {
        Pixels::F32 { nodata, .. } => (1usize, true, *nodata),
        Pixels::U8 { bands, .. } => (*bands, false, None),
    };
    // Every level, from the full resolution down to one tile.
    let mut levels = vec![(
        width,
        height,
        match pixels {
            Pixels::F32 { data, .. } => Level::F32(data.to_vec()),
            Pixels::U8 { data, .. } => Level::U8(data.to_vec()),
        },
    )];
    while let Some((w, h, level)) = levels.last() {
        let (w, h) = (*w, *h);
        if w <= TILE && h <= TILE {
            break;
        }
        let next = match level {
            Level::F32(v) => Level::F32(halve_f32(v, w, h, nodata_value)),
            Level::U8(v) => Level::U8(halve_u8(v, w, h, bands)),
        };
        levels.push((w.div_ceil(2), h.div_ceil(2), next));
    }
    // Compressed tiles per level.
    let tiles: Vec<Vec<Vec<u8>>> = levels
        .iter()
        .map(|(w, h, level)| compress_level(level, *w, *h, bands))
        .collect::<Result<_, _>>()
        .map_err(TiledError::Io)?;

    // Each level's IFD. Its TileOffsets (324) holds one offset per tile: their count, not their
    // values, decides the layout computed next, which then gives them their values.
    let mut ifds: Vec<Vec<Entry>> = Vec::new();
    for (k, (w, h, _)) in levels.iter().enumerate() {
        let n_tiles = tiles[k].len();
        let mut e = vec![
            Entry::longs(254, &[if k == 0 { 0 } else { 1 }]),
            Entry::longs(256, &[*w as u32]),
            Entry::longs(257, &[*h as u32]),
            Entry::shorts(258, &vec![if float { 32 } else { 8 }; bands]),
            Entry::shorts(259, &[8]),
            Entry::shorts(262, &[if bands >= 3 { 2 } else { 1 }]),
            Entry::shorts(277, &[bands as u16]),
            Entry::shorts(284, &[1]),
            Entry::shorts(317, &[if float { 3 } else { 2 }]),
            Entry::shorts(322, &[TILE as u16]),
            Entry::shorts(323, &[TILE as u16]),
            Entry::longs(324, &vec![0; n_tiles]),
            Entry::longs(
                325,
                &tiles[k].iter().map(|t| t.len() as u32).collect::<Vec<_>>(),
            ),
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

    // Layout: header, IFDs, their out-of-line values, tile data smallest level first.
    let mut pos: u64 = 8;
    let mut ifd_pos = Vec::with_capacity(ifds.len());
    for e in &ifds {
        ifd_pos.push(pos);
        pos += 2 + 12 * e.len() as u64 + 4;
    }
    let mut value_pos: Vec<Vec<u64>> = Vec::with_capacity(ifds.len());
    for e in &ifds {
        let mut v = Vec::with_capacity(e.len());
        for entry in e {
            if entry.bytes.len() > 4 {
                pos += pos % 2;
                v.push(pos);
                pos += entry.bytes.len() as u64;
            } else {
                v.push(0);
            }
        }
        value_pos.push(v);
    }
    let mut tile_pos: Vec<Vec<u64>> = vec![Vec::new(); levels.len()];
    for k in (0..levels.len()).rev() {
        for t in &tiles[k] {
            tile_pos[k].push(pos);
            pos += t.len() as u64;
        }
    }
    if pos > u32::MAX as u64 {
        return Err(TiledError::TooLarge(pos));
    }
    for (k, e) in ifds.iter_mut().enumerate() {
        // The entry was made with one zero per tile; same size, now the positions.
        if let Some(entry) = e.iter_mut().find(|e| e.tag == 324) {
            *entry = Entry::longs(
                324,
                &tile_pos[k].iter().map(|&p| p as u32).collect::<Vec<_>>(),
            );
        }
    }

    // Serialise, following the layout.
    let mut out = Positioned { out, at: 0 };
    out.put(b"II")?;
    out.put(&42u16.to_le_bytes())?;
    out.put(&(ifd_pos[0] as u32).to_le_bytes())?;
    for (k, e) in ifds.iter().enumerate() {
        out.put(&(e.len() as u16).to_le_bytes())?;
        for (entry, &at) in e.iter().zip(&value_pos[k]) {
            out.put(&entry.tag.to_le_bytes())?;
            out.put(&entry.kind.to_le_bytes())?;
            out.put(&entry.count.to_le_bytes())?;
            if entry.bytes.len() > 4 {
                out.put(&(at as u32).to_le_bytes())?;
            } else {
                let mut inline = [0u8; 4];
                inline[..entry.bytes.len()].copy_from_slice(&entry.bytes);
                out.put(&inline)?;
            }
        }
        let next = ifd_pos.get(k + 1).copied().unwrap_or(0) as u32;
        out.put(&next.to_le_bytes())?;
    }
    for (k, e) in ifds.iter().enumerate() {
        for (entry, &at) in e.iter().zip(&value_pos[k]) {
            if entry.bytes.len() > 4 {
                out.pad_to(at)?;
                out.put(&entry.bytes)?;
            }
        }
    }
    for k in (0..levels.len()).rev() {
        for (t, &at) in tiles[k].iter().zip(&tile_pos[k]) {
            debug_assert_eq!(out.at, at);
            out.put(t)?;
        }
    }
    Ok(())
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

/// Cuts a level into tiles (edge tiles padded by repeating nothing: zeros, or nodata for
/// floats), applies the predictor and compresses each.
fn compress_level(
    level: &Level,
    w: usize,
    h: usize,
    bands: usize,
) -> std::io::Result<Vec<Vec<u8>>> {
    let across = w.div_ceil(TILE);
    let down = h.div_ceil(TILE);
    (0..across * down)
        .into_par_iter()
        .map(|t| {
            let (tc, tr) = (t % across, t / across);
            let mut raw = Vec::with_capacity(TILE * TILE * bands * 4);
            for r in 0..TILE {
                let y = tr * TILE + r;
                let row_start = raw.len();
                for c in 0..TILE {
                    let x = tc * TILE + c;
                    let inside = x < w && y < h;
                    match level {
                        Level::F32(v) => {
                            let value = if inside { v[y * w + x] } else { 0.0 };
                            raw.extend_from_slice(&value.to_le_bytes());
                        }
                        Level::U8(v) => {
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
                match level {
                    Level::F32(_) => float_predictor(row),
                    Level::U8(_) => {
                        for i in (bands..row.len()).rev() {
                            row[i] = row[i].wrapping_sub(row[i - bands]);
                        }
                    }
                }
            }
            let mut z = ZlibEncoder::new(Vec::new(), Compression::new(6));
            z.write_all(&raw)?;
            z.finish()
        })
        .collect()
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
}
