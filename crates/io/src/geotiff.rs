//! GeoTIFF rasters: float32 single band (DEMs, differences) and RGB(A) u8 (orthomosaics), written
//! with ModelPixelScale, ModelTiepoint, GeoKeyDirectory (EPSG code, pixel-is-area) and GDAL's nodata
//! tag in the cloud-optimised layout of [`crate::tiled_tiff`], and read back from any north-up GeoTIFF with one band of a common numeric type or three/four
//! u8 bands, striped or tiled, compressed or not.
//!
//! Not supported, with an error naming the file: rotated or sheared grids (ModelTransformation or
//! several tie points), user-defined (non-EPSG) or geocentric CRSs, other band layouts.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError};

use crate::coords::Crs;
use crate::tiled_tiff::{
    Entry, Flavour, Pixels, SampleFormat, TiledError, TiledWriter, write_tiled,
};
use crate::{IoError, budget, fsutil};

/// A north-up affine grid, GDAL geotransform style.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeoTransform {
    /// X of the top-left corner of the top-left pixel.
    pub origin_x: f64,
    /// Y of the top-left corner of the top-left pixel.
    pub origin_y: f64,
    /// Pixel width (positive).
    pub pixel_width: f64,
    /// Pixel height (negative for north-up rasters).
    pub pixel_height: f64,
}

impl GeoTransform {
    /// World coordinates of a pixel position (col, row in pixel units, corner convention).
    pub fn pixel_to_world(&self, col: f64, row: f64) -> (f64, f64) {
        (
            self.origin_x + col * self.pixel_width,
            self.origin_y + row * self.pixel_height,
        )
    }

    /// Pixel position of world coordinates.
    pub fn world_to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (x - self.origin_x) / self.pixel_width,
            (y - self.origin_y) / self.pixel_height,
        )
    }
}

/// Georeferencing of a raster.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeoReference {
    /// The grid.
    pub transform: GeoTransform,
    /// The CRS (`Crs::Local` when the file has none).
    pub crs: Crs,
    /// The nodata value, when declared.
    pub nodata: Option<f64>,
    /// Whether the file declared `PixelIsPoint` (the transform here is always corner-based).
    pub pixel_is_point: bool,
}

/// A georeferenced raster with interleaved bands.
#[derive(Debug, Clone, PartialEq)]
pub struct GeoRaster<T> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Bands per pixel.
    pub bands: usize,
    /// Row-major, bands interleaved.
    pub data: Vec<T>,
    /// Georeferencing.
    pub georef: GeoReference,
}

impl<T: Copy> GeoRaster<T> {
    /// Value of band `b` at column `col`, row `row`.
    pub fn get(&self, col: usize, row: usize, b: usize) -> T {
        self.data[(row * self.width + col) * self.bands + b]
    }
}

const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const GEOGRAPHIC_TYPE: u16 = 2048;
const PROJECTED_CS_TYPE: u16 = 3072;
const MODEL_TRANSFORMATION_TAG: u16 = 34264;
const USER_DEFINED: u16 = 32767;
const GDAL_NODATA_TAG: u16 = 42113;

fn geokey_directory(georef: &GeoReference) -> Vec<u16> {
    let mut keys: Vec<[u16; 4]> = Vec::new();
    match georef.crs {
        Crs::Epsg(code) if georef.crs.is_geographic() => {
            keys.push([GT_MODEL_TYPE, 0, 1, 2]);
            keys.push([GT_RASTER_TYPE, 0, 1, 1 + georef.pixel_is_point as u16]);
            keys.push([GEOGRAPHIC_TYPE, 0, 1, code]);
        }
        Crs::Epsg(code) => {
            keys.push([GT_MODEL_TYPE, 0, 1, 1]);
            keys.push([GT_RASTER_TYPE, 0, 1, 1 + georef.pixel_is_point as u16]);
            keys.push([PROJECTED_CS_TYPE, 0, 1, code]);
        }
        Crs::Local => keys.push([GT_RASTER_TYPE, 0, 1, 1 + georef.pixel_is_point as u16]),
    }
    let mut dir = vec![1, 1, 0, keys.len() as u16];
    dir.extend(keys.into_iter().flatten());
    dir
}

fn tiff_err(path: &Path, e: TiffError) -> IoError {
    match e {
        TiffError::IoError(e) => IoError::io(path, e),
        TiffError::UnsupportedError(u) => IoError::unsupported(path, "TIFF layout", u.to_string()),
        other => IoError::invalid(path, format!("invalid TIFF: {other}")),
    }
}

fn format_nodata(v: f64) -> String {
    // Shortest representation that reads back to the same value, as GDAL writes integers.
    format!("{v}")
}

/// The GeoTIFF tags of a raster: pixel scale, tie point, GeoKey directory.
fn georef_entries(georef: &GeoReference) -> Vec<Entry> {
    let t = &georef.transform;
    let shift = if georef.pixel_is_point { 0.5 } else { 0.0 };
    let (tx, ty) = t.pixel_to_world(shift, shift);
    vec![
        Entry::doubles(33550, &[t.pixel_width, -t.pixel_height, 0.0]),
        Entry::doubles(33922, &[0.0, 0.0, 0.0, tx, ty, 0.0]),
        Entry::shorts(34735, &geokey_directory(georef)),
    ]
}

/// Writes `pixels` as a tiled, compressed GeoTIFF with overviews, atomically.
fn write_geotiff(
    path: &Path,
    width: usize,
    height: usize,
    pixels: Pixels<'_>,
    georef: &GeoReference,
) -> Result<(), IoError> {
    check_north_up(path, georef)?;
    let nodata = georef
        .nodata
        .map(|v| Entry::ascii(GDAL_NODATA_TAG, &format_nodata(v)));
    fsutil::write_atomically(path, |w| {
        write_tiled(
            w,
            width,
            height,
            pixels,
            &georef_entries(georef),
            nodata.as_ref(),
        )
        .map_err(|e| tiled_error(path, e))
    })
}

fn tiled_error(path: &Path, e: TiledError) -> IoError {
    match e {
        TiledError::Io(e) => IoError::io(path, e),
        TiledError::Rows(message) => IoError::invalid(path, message),
    }
}

/// Checks what both writers refuse: a grid that is not north-up.
fn check_north_up(path: &Path, georef: &GeoReference) -> Result<(), IoError> {
    let t = &georef.transform;
    if !(t.pixel_width > 0.0 && t.pixel_height < 0.0) {
        return Err(IoError::unsupported(
            path,
            "grid",
            "only north-up rasters (pixel width > 0, pixel height < 0) are written",
        ));
    }
    Ok(())
}

/// A GeoTIFF written a band of rows at a time, for rasters larger than memory (orthomosaics):
/// the same file as [`write_f32`], [`write_rgb8`] or [`write_u8`] would write from the whole
/// raster, BigTIFF beyond 4 GiB. Memory holds one band of [`crate::tiled_tiff::TILE`] rows per
/// overview level; the compressed tiles wait in a spool file beside the output
/// (`.<name>.tmp-<pid>.tiles`, removed when the writer is finished or dropped), and the file
/// appears at its path only when [`GeoTiffWriter::finish`] succeeds.
pub struct GeoTiffWriter {
    path: PathBuf,
    spool: SpoolFile,
    georef: GeoReference,
    flavour: Flavour,
    tiles: TiledWriter<File>,
}

impl GeoTiffWriter {
    /// Starts `path`: `width` × `height` pixels of `format` (RGB(A) or grey u8, or float32 whose
    /// nodata is `georef`'s).
    pub fn create(
        path: &Path,
        width: usize,
        height: usize,
        format: SampleFormat,
        georef: &GeoReference,
    ) -> Result<GeoTiffWriter, IoError> {
        check_north_up(path, georef)?;
        let format_ok = match format {
            SampleFormat::F32 { nodata } => nodata == georef.nodata.map(|v| v as f32),
            SampleFormat::U8 { bands } => matches!(bands, 1 | 3 | 4),
        };
        if width == 0
            || height == 0
            || width > u32::MAX as usize
            || height > u32::MAX as usize
            || !format_ok
        {
            return Err(IoError::invalid(
                path,
                format!("cannot write {width} × {height} pixels of {format:?}"),
            ));
        }
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|e| IoError::io(parent, e))?;
        }
        // A temporary name of the output's (`.<name>.tmp-<pid>.tiles`), which a later run
        // removes if this process is killed.
        let mut spool_path = fsutil::temporary_path(path).into_os_string();
        spool_path.push(".tiles");
        let spool_path = PathBuf::from(spool_path);
        let spool = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&spool_path)
            .map_err(|e| IoError::io(&spool_path, e))?;
        Ok(GeoTiffWriter {
            path: path.to_path_buf(),
            spool: SpoolFile(spool_path),
            georef: *georef,
            flavour: Flavour::Auto,
            tiles: TiledWriter::new(width, height, format, spool),
        })
    }

    /// Writes BigTIFF whatever the size (files of GIS tools that need one layout).
    pub fn big_tiff(mut self) -> GeoTiffWriter {
        self.flavour = Flavour::BigTiff;
        self
    }

    /// Appends whole rows below those already given.
    pub fn push_rows(&mut self, pixels: Pixels<'_>) -> Result<(), IoError> {
        self.tiles
            .push_rows(pixels)
            .map_err(|e| tiled_error(&self.spool.0, e))
    }

    /// Writes the file (atomically) once every row has been given.
    pub fn finish(self) -> Result<(), IoError> {
        let GeoTiffWriter {
            path,
            spool,
            georef,
            flavour,
            tiles,
        } = self;
        let nodata = georef
            .nodata
            .map(|v| Entry::ascii(GDAL_NODATA_TAG, &format_nodata(v)));
        let written = fsutil::write_atomically(&path, |w| {
            tiles
                .finish(w, &georef_entries(&georef), nodata.as_ref(), flavour)
                .map_err(|e| tiled_error(&path, e))
        });
        drop(spool);
        written
    }
}

/// The spool file of a [`GeoTiffWriter`], removed when the writer is done with it.
struct SpoolFile(PathBuf);

impl Drop for SpoolFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn check_size<T>(path: &Path, raster: &GeoRaster<T>, bands: &[usize]) -> Result<(), IoError> {
    if !bands.contains(&raster.bands)
        || raster.data.len() != raster.width * raster.height * raster.bands
        || raster.width == 0
        || raster.height == 0
        || raster.width > u32::MAX as usize
        || raster.height > u32::MAX as usize
    {
        return Err(IoError::invalid(
            path,
            format!(
                "raster of {}x{}x{} does not match its {} values or the band count {:?}",
                raster.width,
                raster.height,
                raster.bands,
                raster.data.len(),
                bands
            ),
        ));
    }
    Ok(())
}

/// Writes a single-band float32 GeoTIFF (tiled, Deflate-compressed, with overviews), atomically.
pub fn write_f32(path: &Path, raster: &GeoRaster<f32>) -> Result<(), IoError> {
    check_size(path, raster, &[1])?;
    let pixels = Pixels::F32 {
        data: &raster.data,
        nodata: raster.georef.nodata.map(|v| v as f32),
    };
    write_geotiff(path, raster.width, raster.height, pixels, &raster.georef)
}

/// Writes an RGB or RGBA u8 GeoTIFF (band 4 marked as alpha; tiled, compressed, with overviews),
/// atomically.
pub fn write_rgb8(path: &Path, raster: &GeoRaster<u8>) -> Result<(), IoError> {
    check_size(path, raster, &[3, 4])?;
    let pixels = Pixels::U8 {
        data: &raster.data,
        bands: raster.bands,
    };
    write_geotiff(path, raster.width, raster.height, pixels, &raster.georef)
}

/// Writes a single-band u8 GeoTIFF (masks, flags; tiled, compressed, with overviews),
/// atomically.
pub fn write_u8(path: &Path, raster: &GeoRaster<u8>) -> Result<(), IoError> {
    check_size(path, raster, &[1])?;
    let pixels = Pixels::U8 {
        data: &raster.data,
        bands: 1,
    };
    write_geotiff(path, raster.width, raster.height, pixels, &raster.georef)
}

/// The decoded samples of a GeoTIFF before conversion.
struct Decoded {
    grid: RasterGrid,
    colortype: ColorType,
    samples: DecodingResult,
}

/// Limits while the header and tags are read: a tag value (tie points, GeoKeys, GDAL
/// metadata) over 16 MiB is not one a raster of timesift's needs, and a larger claim is refused
/// before it is allocated.
fn header_limits() -> Limits {
    let mut limits = Limits::default();
    limits.decoding_buffer_size = 16 << 20;
    limits.intermediate_buffer_size = 16 << 20;
    limits.ifd_value_size = 16 << 20;
    limits
}

/// Limits while the samples are decoded: the whole image (`decoded_bytes`, checked to be
/// allocatable) and one compressed strip or tile, which cannot be longer than the file.
fn sample_limits(decoded_bytes: u64, file_len: u64) -> Limits {
    let mut limits = header_limits();
    limits.decoding_buffer_size = usize::try_from(decoded_bytes).unwrap_or(usize::MAX);
    limits.intermediate_buffer_size =
        usize::try_from(file_len.saturating_add(1 << 20)).unwrap_or(usize::MAX);
    limits
}

/// Bits per pixel of a colour type (`None` for depths a sample cannot have).
fn bits_per_pixel(colortype: ColorType) -> Option<u64> {
    let (bits, samples) = match colortype {
        ColorType::Gray(b) | ColorType::Palette(b) => (b, 1),
        ColorType::GrayA(b) => (b, 2),
        ColorType::RGB(b) | ColorType::YCbCr(b) | ColorType::Lab(b) => (b, 3),
        ColorType::RGBA(b) | ColorType::CMYK(b) => (b, 4),
        ColorType::CMYKA(b) => (b, 5),
        ColorType::Multiband {
            bit_depth,
            num_samples,
        } => (bit_depth, num_samples),
        // A colour type of a later tiff release: its size is not known here.
        _ => return None,
    };
    (bits > 0 && bits <= 64 && samples > 0).then(|| u64::from(bits) * u64::from(samples))
}

/// The size and georeference of a GeoTIFF, its samples not decoded: what is needed to put other
/// data on its grid (`timesift dem --like`).
#[derive(Debug, Clone, PartialEq)]
pub struct RasterGrid {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Placement, CRS and nodata.
    pub georef: GeoReference,
}

/// Reads the size and georeference of a GeoTIFF without decoding its samples.
pub fn read_grid(path: &Path) -> Result<RasterGrid, IoError> {
    let (_, _, grid) = open_georeferenced(path)?;
    Ok(grid)
}

/// Decodes the samples of the first image once the size its header claims is known to be
/// allocatable, with room for a copy as f32 (what [`read_f32`] and [`read_bands_f32`] make).
fn read_georeferenced(path: &Path) -> Result<Decoded, IoError> {
    let (decoder, colortype, grid) = open_georeferenced(path)?;
    let bits = bits_per_pixel(colortype).ok_or_else(|| {
        IoError::unsupported(path, "GeoTIFF sample type", format!("{colortype:?}"))
    })?;
    let cells = grid.width as u64 * grid.height as u64;
    let decoded = cells.saturating_mul(bits).div_ceil(8);
    let as_f32 = cells.saturating_mul(bits.div_ceil(8)).saturating_mul(4);
    let file_len = std::fs::metadata(path)
        .map_err(|e| IoError::io(path, e))?
        .len();
    budget::check_expansion(
        path,
        decoded,
        file_len,
        budget::MAX_RASTER_EXPANSION,
        "the raster",
    )?;
    budget::ensure_allocatable(path, decoded.saturating_add(as_f32), "the raster")?;
    let mut decoder = decoder.with_limits(sample_limits(decoded, file_len));
    let samples = decoder.read_image().map_err(|e| tiff_err(path, e))?;
    Ok(Decoded {
        grid,
        colortype,
        samples,
    })
}

/// A decoder positioned on the first image, with the image's colour type, size and georeference.
fn open_georeferenced(
    path: &Path,
) -> Result<(Decoder<BufReader<File>>, ColorType, RasterGrid), IoError> {
    let file = File::open(path).map_err(|e| IoError::io(path, e))?;
    let err = |e| tiff_err(path, e);
    let mut decoder = Decoder::new(BufReader::new(file))
        .map_err(err)?
        .with_limits(header_limits());
    let (width, height) = decoder.dimensions().map_err(err)?;
    budget::check_cells(path, width.into(), height.into(), "the raster")?;
    let colortype = decoder.colortype().map_err(err)?;
    let (scale, tie) = pixel_scale_and_tiepoint(&mut decoder, path)?;
    let (crs, pixel_is_point) = crs_and_raster_type(&mut decoder, path)?;
    let nodata = gdal_nodata(&mut decoder, path)?;
    let grid = RasterGrid {
        width: width as usize,
        height: height as usize,
        georef: GeoReference {
            transform: transform_of_tiepoint(&scale, &tie, pixel_is_point),
            crs,
            nodata,
            pixel_is_point,
        },
    };
    Ok((decoder, colortype, grid))
}

/// The ModelPixelScale and the one ModelTiepoint of a north-up grid; any other placement
/// (a ModelTransformation, several tie points, a south-up or degenerate scale) is refused.
fn pixel_scale_and_tiepoint(
    decoder: &mut Decoder<BufReader<File>>,
    path: &Path,
) -> Result<(Vec<f64>, Vec<f64>), IoError> {
    let err = |e| tiff_err(path, e);
    if decoder
        .find_tag(Tag::Unknown(MODEL_TRANSFORMATION_TAG))
        .map_err(err)?
        .is_some()
    {
        return Err(IoError::unsupported(
            path,
            "GeoTIFF layout",
            "ModelTransformationTag (rotated or sheared grid); only north-up grids are read",
        ));
    }
    let scale = decoder
        .find_tag(Tag::ModelPixelScaleTag)
        .map_err(err)?
        .map(|v| v.into_f64_vec())
        .transpose()
        .map_err(err)?;
    let tie = decoder
        .find_tag(Tag::ModelTiepointTag)
        .map_err(err)?
        .map(|v| v.into_f64_vec())
        .transpose()
        .map_err(err)?;
    let (Some(scale), Some(tie)) = (scale, tie) else {
        return Err(IoError::unsupported(
            path,
            "GeoTIFF layout",
            "not georeferenced (ModelPixelScale and ModelTiepoint are required)",
        ));
    };
    if scale.len() < 2 || tie.len() != 6 {
        return Err(IoError::unsupported(
            path,
            "GeoTIFF layout",
            format!(
                "{} tie points; exactly one tie point with a pixel scale is supported",
                tie.len() / 6
            ),
        ));
    }
    if !(scale[0] > 0.0 && scale[0].is_finite() && scale[1].is_finite()) || scale[1] == 0.0 {
        return Err(IoError::invalid(
            path,
            "ModelPixelScale must be finite and non-zero",
        ));
    }
    if scale[1] < 0.0 {
        return Err(IoError::unsupported(
            path,
            "GeoTIFF layout",
            "south-up grid (negative ModelPixelScale y); only north-up grids are read",
        ));
    }
    if !tie.iter().all(|v| v.is_finite()) {
        return Err(IoError::invalid(
            path,
            "ModelTiepoint holds non-finite values",
        ));
    }
    Ok((scale, tie))
}

/// The CRS the GeoKey directory names (EPSG codes only; none is a local CRS) and whether the
/// raster is PixelIsPoint.
fn crs_and_raster_type(
    decoder: &mut Decoder<BufReader<File>>,
    path: &Path,
) -> Result<(Crs, bool), IoError> {
    let err = |e| tiff_err(path, e);
    let keys = decoder
        .find_tag(Tag::GeoKeyDirectoryTag)
        .map_err(err)?
        .map(|v| v.into_u16_vec())
        .transpose()
        .map_err(err)?
        .unwrap_or_default();
    let key = |id: u16| {
        keys.get(4..)
            .unwrap_or(&[])
            .chunks_exact(4)
            .find(|k| k[0] == id && k[1] == 0)
            .map(|k| k[3])
    };
    let pixel_is_point = key(GT_RASTER_TYPE) == Some(2);
    let crs = match key(GT_MODEL_TYPE) {
        Some(1) => match key(PROJECTED_CS_TYPE) {
            Some(USER_DEFINED) | None => {
                return Err(IoError::unsupported(
                    path,
                    "GeoTIFF CRS",
                    "user-defined projected CRS; only EPSG-coded CRSs are supported",
                ));
            }
            Some(code) => Crs::Epsg(code),
        },
        Some(2) => match key(GEOGRAPHIC_TYPE) {
            Some(USER_DEFINED) | None => {
                return Err(IoError::unsupported(
                    path,
                    "GeoTIFF CRS",
                    "user-defined geographic CRS; only EPSG-coded CRSs are supported",
                ));
            }
            Some(code) => Crs::Epsg(code),
        },
        Some(other) => {
            return Err(IoError::unsupported(
                path,
                "GeoTIFF CRS",
                format!("model type {other} (geocentric or unknown)"),
            ));
        }
        None => Crs::Local,
    };
    Ok((crs, pixel_is_point))
}

/// The GDAL_NODATA value, when the file has one.
fn gdal_nodata(
    decoder: &mut Decoder<BufReader<File>>,
    path: &Path,
) -> Result<Option<f64>, IoError> {
    let err = |e| tiff_err(path, e);
    decoder
        .find_tag(Tag::GdalNodata)
        .map_err(err)?
        .map(|v| v.into_string())
        .transpose()
        .map_err(err)?
        .map(|s| {
            let s = s.trim_matches(char::from(0)).trim().to_string();
            s.parse::<f64>()
                .map_err(|_| IoError::invalid(path, format!("GDAL_NODATA \"{s}\" is not a number")))
        })
        .transpose()
}

/// The grid's placement from its pixel scale and tie point (shifted half a pixel for
/// PixelIsPoint): pixel height negative, north up.
fn transform_of_tiepoint(scale: &[f64], tie: &[f64], pixel_is_point: bool) -> GeoTransform {
    let (pw, ph) = (scale[0], -scale[1]);
    let shift = if pixel_is_point { 0.5 } else { 0.0 };
    GeoTransform {
        origin_x: tie[3] - (tie[0] + shift) * pw,
        origin_y: tie[4] - (tie[1] + shift) * ph,
        pixel_width: pw,
        pixel_height: ph,
    }
}

/// Reads a single-band GeoTIFF of any common numeric sample type as f32.
pub fn read_f32(path: &Path) -> Result<GeoRaster<f32>, IoError> {
    let d = read_georeferenced(path)?;
    if !matches!(d.colortype, ColorType::Gray(_)) {
        return Err(IoError::unsupported(
            path,
            "GeoTIFF layout",
            format!("{:?}; a single-band raster was expected", d.colortype),
        ));
    }
    let data = samples_f32(path, d.samples)?;
    if data.len() != d.grid.width * d.grid.height {
        return Err(sample_count_error(path, data.len(), &d.grid));
    }
    Ok(GeoRaster {
        width: d.grid.width,
        height: d.grid.height,
        bands: 1,
        data,
        georef: d.grid.georef,
    })
}

/// Reads a GeoTIFF with any number of bands (RGB, RGBA, multiband, even 16-bit "RGB" stored as
/// integers, as some orthophoto exports do) of any common numeric sample type as f32, values
/// unscaled.
pub fn read_bands_f32(path: &Path) -> Result<GeoRaster<f32>, IoError> {
    let d = read_georeferenced(path)?;
    let data = samples_f32(path, d.samples)?;
    let pixels = d.grid.width * d.grid.height;
    if pixels == 0 || data.len() % pixels != 0 {
        return Err(sample_count_error(path, data.len(), &d.grid));
    }
    Ok(GeoRaster {
        width: d.grid.width,
        height: d.grid.height,
        bands: data.len() / pixels,
        data,
        georef: d.grid.georef,
    })
}

/// A decoder that returned another number of samples than the grid holds.
fn sample_count_error(path: &Path, samples: usize, grid: &RasterGrid) -> IoError {
    IoError::invalid(
        path,
        format!(
            "{samples} samples for {} × {} pixels",
            grid.width, grid.height
        ),
    )
}

fn samples_f32(path: &Path, samples: DecodingResult) -> Result<Vec<f32>, IoError> {
    Ok(match samples {
        DecodingResult::F32(v) => v,
        DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I8(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::I32(v) => v.into_iter().map(|x| x as f32).collect(),
        _ => {
            return Err(IoError::unsupported(
                path,
                "GeoTIFF sample type",
                "only 8/16/32-bit integers and 32/64-bit floats are read",
            ));
        }
    })
}

/// Reads an RGB or RGBA u8 GeoTIFF.
pub fn read_rgb8(path: &Path) -> Result<GeoRaster<u8>, IoError> {
    let d = read_georeferenced(path)?;
    let bands = match (d.colortype, &d.samples) {
        (ColorType::RGB(8), DecodingResult::U8(_)) => 3,
        (ColorType::RGBA(8), DecodingResult::U8(_)) => 4,
        (other, _) => {
            return Err(IoError::unsupported(
                path,
                "GeoTIFF layout",
                format!("{other:?}; 8-bit RGB or RGBA was expected"),
            ));
        }
    };
    let DecodingResult::U8(data) = d.samples else {
        return Err(IoError::invalid(path, "unexpected sample type"));
    };
    if data.len() != d.grid.width * d.grid.height * bands {
        return Err(IoError::invalid(
            path,
            format!(
                "{} samples for {} × {} pixels of {bands} bands",
                data.len(),
                d.grid.width,
                d.grid.height
            ),
        ));
    }
    Ok(GeoRaster {
        width: d.grid.width,
        height: d.grid.height,
        bands,
        data,
        georef: d.grid.georef,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tiff::encoder::{TiffEncoder, colortype};

    fn georef() -> GeoReference {
        GeoReference {
            transform: GeoTransform {
                origin_x: 731413.76093,
                origin_y: 5705559.76249,
                pixel_width: 1.001249756097561,
                pixel_height: -1.000769832134293,
            },
            crs: Crs::Epsg(32754),
            nodata: Some(-32767.0),
            pixel_is_point: false,
        }
    }

    #[test]
    fn float_and_rgba_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("dem.tif");
        let r = GeoRaster {
            width: 7,
            height: 5,
            bands: 1,
            data: (0..35).map(|i| i as f32 * 0.25 - 3.0).collect(),
            georef: georef(),
        };
        write_f32(&p, &r).unwrap();
        assert_eq!(read_f32(&p).unwrap(), r);

        let p = dir.path().join("ortho.tif");
        let mut g = georef();
        g.nodata = None;
        g.crs = Crs::Epsg(4326);
        g.pixel_is_point = true;
        let r = GeoRaster {
            width: 3,
            height: 2,
            bands: 4,
            data: (0..24).map(|i| (i * 10) as u8).collect(),
            georef: g,
        };
        write_rgb8(&p, &r).unwrap();
        let back = read_rgb8(&p).unwrap();
        assert_eq!(back.data, r.data);
        assert_eq!(back.georef.crs, Crs::Epsg(4326));
        assert!(back.georef.pixel_is_point);
        assert!((back.georef.transform.origin_x - g.transform.origin_x).abs() < 1e-9);
        assert!(
            read_f32(&p)
                .unwrap_err()
                .to_string()
                .contains("single-band")
        );
    }

    #[test]
    fn rotated_grid_is_reported_as_unsupported() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rotated.tif");
        let file = std::fs::File::create(&p).unwrap();
        let mut enc = TiffEncoder::new(std::io::BufWriter::new(file)).unwrap();
        let mut img = enc.new_image::<colortype::Gray32Float>(2, 2).unwrap();
        let m = [
            0.7, -0.7, 0.0, 10.0, 0.7, 0.7, 0.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        img.encoder()
            .write_tag(Tag::Unknown(MODEL_TRANSFORMATION_TAG), &m[..])
            .unwrap();
        img.write_data(&[0.0f32; 4]).unwrap();
        drop(enc);
        let e = read_f32(&p).unwrap_err().to_string();
        assert!(
            e.contains("rotated.tif") && e.contains("unsupported"),
            "{e}"
        );
        assert!(!e.contains('\n'));
    }
}
