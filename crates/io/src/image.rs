//! Image decoding to f32 (grey or RGB), for JPEG, PNG and TIFF in 8 or 16 bits.
//!
//! Pixel values are scaled to [0, 1] whatever the bit depth, so that thresholds downstream do not
//! depend on the file format. The EXIF orientation flag is deliberately ignored: photogrammetry needs
//! the sensor's own pixel grid, the one the camera model describes.

use std::path::Path;

use image::{DynamicImage, ImageDecoder, ImageReader, Limits};

use crate::{IoError, budget};

/// A decoded image with interleaved channels, values in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct ImageF32 {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// 1 for grey, 3 for RGB.
    pub channels: u32,
    /// Row-major, channels interleaved.
    pub data: Vec<f32>,
}

impl ImageF32 {
    /// The value of channel `c` at column `x`, row `y`.
    pub fn get(&self, x: u32, y: u32, c: u32) -> f32 {
        self.data[((y as usize * self.width as usize + x as usize) * self.channels as usize)
            + c as usize]
    }
}

/// Decodes an image whose decoded form, plus a conversion of `out_bytes_per_pixel` bytes per
/// pixel, fits in memory: the header's size is checked ([`budget::check_cells`]) and the memory
/// it claims is known to be there before the decoder allocates it (a decoder's failed
/// allocation aborts the process).
fn decode(path: &Path, out_bytes_per_pixel: u64) -> Result<DynamicImage, IoError> {
    check_signature(path)?;
    let mut reader = ImageReader::open(path)
        .map_err(|e| IoError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| IoError::io(path, e))?;
    // Scans of archival photos exceed the default 512 MiB decoding limit: the bound is the
    // one every raster of timesift has, checked below with the memory it needs.
    let mut limits = Limits::default();
    limits.max_image_width = Some(budget::MAX_SIDE as u32);
    limits.max_image_height = Some(budget::MAX_SIDE as u32);
    limits.max_alloc = None;
    reader.limits(limits);
    let decoder = reader.into_decoder().map_err(|e| decode_error(path, e))?;
    let (width, height) = decoder.dimensions();
    let cells = budget::check_cells(path, width.into(), height.into(), "the image")?;
    let file_len = std::fs::metadata(path)
        .map_err(|e| IoError::io(path, e))?
        .len();
    budget::check_expansion(
        path,
        decoder.total_bytes(),
        file_len,
        budget::MAX_RASTER_EXPANSION,
        "the image",
    )?;
    let needed = decoder
        .total_bytes()
        .saturating_add(cells.saturating_mul(out_bytes_per_pixel));
    budget::ensure_allocatable(path, needed, "decoding the image")?;
    DynamicImage::from_decoder(decoder).map_err(|e| decode_error(path, e))
}

/// Refuses a file named as a JPEG, PNG or TIFF whose first bytes are those of no image format
/// (a text file, an HTML page saved as `.jpg`, a zero-filled download): said plainly, not as a
/// decoder's complaint about its markers.
fn check_signature(path: &Path) -> Result<(), IoError> {
    use std::io::Read;
    let named = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .is_some_and(|e| ["jpg", "jpeg", "png", "tif", "tiff"].contains(&e.as_str()));
    if !named {
        return Ok(());
    }
    let mut head = [0u8; 16];
    let mut file = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let mut n = 0;
    while n < head.len() {
        match file.read(&mut head[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(IoError::io(path, e)),
        }
    }
    if image::guess_format(&head[..n]).is_ok() {
        return Ok(());
    }
    let shown: Vec<String> = head[..n.min(4)]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    Err(IoError::invalid(
        path,
        match n {
            0 => "not an image: the file is empty".to_string(),
            _ => format!(
                "not an image: it starts with the bytes {}, which begin no JPEG, PNG or TIFF \
                 file",
                shown.join(" ")
            ),
        },
    ))
}

fn decode_error(path: &Path, e: image::ImageError) -> IoError {
    match e {
        image::ImageError::Unsupported(u) => {
            IoError::unsupported(path, "image format", u.to_string())
        }
        other => IoError::invalid(path, format!("cannot decode image: {other}")),
    }
}

/// Reads an image as grey f32 (ITU-R 601 luma for colour images).
pub fn read_grey(path: &Path) -> Result<ImageF32, IoError> {
    let img = decode(path, 4)?.to_luma32f();
    Ok(ImageF32 {
        width: img.width(),
        height: img.height(),
        channels: 1,
        data: img.into_raw(),
    })
}

/// Reads an image as RGB f32 (grey images are replicated to three channels).
pub fn read_rgb(path: &Path) -> Result<ImageF32, IoError> {
    let img = decode(path, 12)?.to_rgb32f();
    Ok(ImageF32 {
        width: img.width(),
        height: img.height(),
        channels: 3,
        data: img.into_raw(),
    })
}

/// Reads an image as 8-bit RGB (16-bit images are scaled down, grey ones replicated): what
/// orthomosaics sample.
pub fn read_rgb8(path: &Path) -> Result<(u32, u32, Vec<u8>), IoError> {
    let img = decode(path, 3)?.to_rgb8();
    Ok((img.width(), img.height(), img.into_raw()))
}

/// Reads an image as 8-bit RGBA (opaque where it has no alpha): an orthomosaic's part as the
/// ortho step wrote it.
pub fn read_rgba8(path: &Path) -> Result<(u32, u32, Vec<u8>), IoError> {
    let img = decode(path, 4)?.to_rgba8();
    Ok((img.width(), img.height(), img.into_raw()))
}

/// Writes an 8-bit PNG of 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA) channels, atomically.
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    channels: u8,
    data: &[u8],
) -> Result<(), IoError> {
    let colour = png_colour(path, width, height, channels, data)?;
    crate::fsutil::write_atomically(path, |w| {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new(w)
            .write_image(data, width, height, colour)
            .map_err(|e| IoError::invalid(path, format!("cannot encode PNG: {e}")))
    })
}

/// An 8-bit PNG of 1 to 4 channels as bytes (to inline in a page), `name` saying what it is
/// in messages.
pub fn encode_png(
    name: &Path,
    width: u32,
    height: u32,
    channels: u8,
    data: &[u8],
) -> Result<Vec<u8>, IoError> {
    use image::ImageEncoder;
    let colour = png_colour(name, width, height, channels, data)?;
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes)
        .write_image(data, width, height, colour)
        .map_err(|e| IoError::invalid(name, format!("cannot encode PNG: {e}")))?;
    Ok(bytes)
}

/// The PNG colour type of `channels`, which `data` must fill for `width × height`.
fn png_colour(
    path: &Path,
    width: u32,
    height: u32,
    channels: u8,
    data: &[u8],
) -> Result<image::ExtendedColorType, IoError> {
    let colour = match channels {
        1 => image::ExtendedColorType::L8,
        2 => image::ExtendedColorType::La8,
        3 => image::ExtendedColorType::Rgb8,
        4 => image::ExtendedColorType::Rgba8,
        _ => {
            return Err(IoError::invalid(
                path,
                format!("{channels} channels; a PNG has 1 to 4"),
            ));
        }
    };
    if data.len() != width as usize * height as usize * channels as usize {
        return Err(IoError::invalid(
            path,
            format!("{} bytes for {width} × {height} × {channels}", data.len()),
        ));
    }
    Ok(colour)
}

/// Width and height of an image, reading only its header.
pub fn dimensions(path: &Path) -> Result<(u32, u32), IoError> {
    ImageReader::open(path)
        .map_err(|e| IoError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| IoError::io(path, e))?
        .into_dimensions()
        .map_err(|e| IoError::invalid(path, format!("cannot read image header: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageBuffer, Luma, Rgb};

    #[test]
    fn eight_and_sixteen_bit_scale_to_unit_range() {
        let dir = tempfile::tempdir().unwrap();
        let p8 = dir.path().join("g8.png");
        ImageBuffer::<Luma<u8>, _>::from_fn(4, 3, |x, y| Luma([(x * 60 + y) as u8]))
            .save(&p8)
            .unwrap();
        let g = read_grey(&p8).unwrap();
        assert_eq!((g.width, g.height, g.channels), (4, 3, 1));
        assert!((g.get(3, 2, 0) - 182.0 / 255.0).abs() < 1e-6);

        let p16 = dir.path().join("c16.tif");
        ImageBuffer::<Rgb<u16>, _>::from_fn(5, 2, |x, _| Rgb([65535, (x * 1000) as u16, 0]))
            .save(&p16)
            .unwrap();
        let c = read_rgb(&p16).unwrap();
        assert_eq!((c.width, c.height, c.channels), (5, 2, 3));
        assert!((c.get(0, 0, 0) - 1.0).abs() < 1e-6);
        assert!((c.get(4, 1, 1) - 4000.0 / 65535.0).abs() < 1e-6);
        assert_eq!(dimensions(&p16).unwrap(), (5, 2));
        // Grey from colour is the luma.
        let grey = read_grey(&p16).unwrap();
        assert!(grey.get(0, 0, 0) > 0.2 && grey.get(0, 0, 0) < 0.35);
    }

    #[test]
    fn corrupt_jpeg_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("broken.jpg");
        // A JPEG start-of-image marker followed by garbage.
        std::fs::write(&p, [0xFF, 0xD8, 0xFF, 0xE0, 0, 16, b'J', b'F', 1, 2, 3]).unwrap();
        let err = read_grey(&p).unwrap_err().to_string();
        assert!(err.contains("broken.jpg"), "{err}");
        assert!(!err.contains('\n'));
    }
}
