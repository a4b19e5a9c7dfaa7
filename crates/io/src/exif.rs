//! The EXIF facts photogrammetry needs: focal length (true and 35 mm equivalent), sensor size when
//! the focal-plane resolution is recorded, GPS position, and the capture time.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use exif::{In, Tag, Value};

use crate::IoError;

/// A GPS position as recorded by the camera (WGS84 degrees, altitude in metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpsPosition {
    /// Latitude, degrees, north positive.
    pub latitude: f64,
    /// Longitude, degrees, east positive.
    pub longitude: f64,
    /// Altitude in metres (negative below the reference), when recorded.
    pub altitude: Option<f64>,
}

/// EXIF metadata of one image. Every field is optional: scans and many drones omit some.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ExifInfo {
    /// Camera maker.
    pub make: Option<String>,
    /// Camera model.
    pub model: Option<String>,
    /// Focal length in millimetres.
    pub focal_length_mm: Option<f64>,
    /// 35 mm-equivalent focal length in millimetres.
    pub focal_length_35mm: Option<f64>,
    /// Sensor width and height in millimetres, from the focal-plane resolution and the pixel size.
    pub sensor_size_mm: Option<(f64, f64)>,
    /// Pixel dimensions recorded in EXIF.
    pub pixel_dimensions: Option<(u32, u32)>,
    /// GPS position.
    pub gps: Option<GpsPosition>,
    /// Capture time as written (`YYYY:MM:DD HH:MM:SS`).
    pub timestamp: Option<String>,
}

impl ExifInfo {
    /// Focal length in pixels for an image `width` pixels wide, from the true focal length and the
    /// sensor width, or else from the 35 mm equivalent (36 mm frame width, landscape).
    pub fn focal_length_px(&self, width: u32, height: u32) -> Option<f64> {
        let long_side = width.max(height) as f64;
        if let (Some(f), Some((sw, sh))) = (self.focal_length_mm, self.sensor_size_mm) {
            let sensor_long = sw.max(sh);
            if f > 0.0 && sensor_long > 0.0 {
                return Some(f / sensor_long * long_side);
            }
        }
        self.focal_length_35mm
            .filter(|f| *f > 0.0)
            .map(|f35| f35 / 36.0 * long_side)
    }
}

fn rational(value: &Value, index: usize) -> Option<f64> {
    match value {
        Value::Rational(v) => v.get(index).filter(|r| r.denom != 0).map(|r| r.to_f64()),
        Value::SRational(v) => v.get(index).filter(|r| r.denom != 0).map(|r| r.to_f64()),
        Value::Short(v) => v.get(index).map(|&s| s as f64),
        Value::Long(v) => v.get(index).map(|&s| s as f64),
        _ => None,
    }
}

fn ascii(value: &Value) -> Option<String> {
    match value {
        Value::Ascii(parts) => parts
            .first()
            .map(|b| String::from_utf8_lossy(b).trim().to_string())
            .filter(|s| !s.is_empty()),
        _ => None,
    }
}

fn dms_degrees(value: &Value) -> Option<f64> {
    let d = rational(value, 0)?;
    let m = rational(value, 1).unwrap_or(0.0);
    let s = rational(value, 2).unwrap_or(0.0);
    Some(d + m / 60.0 + s / 3600.0)
}

/// Reads the EXIF block of an image. A file without EXIF gives an empty [`ExifInfo`]; a file that
/// cannot be opened, or whose EXIF is corrupt, is an error naming it.
pub fn read_exif(path: &Path) -> Result<ExifInfo, IoError> {
    let file = File::open(path).map_err(|e| IoError::io(path, e))?;
    let exif = match exif::Reader::new().read_from_container(&mut BufReader::new(file)) {
        Ok(exif) => exif,
        Err(exif::Error::NotFound(_)) => return Ok(ExifInfo::default()),
        Err(exif::Error::Io(e)) => return Err(IoError::io(path, e)),
        Err(e) => return Err(IoError::invalid(path, format!("corrupt EXIF: {e}"))),
    };
    let field = |tag: Tag| exif.get_field(tag, In::PRIMARY).map(|f| &f.value);
    let text = |tag: Tag| field(tag).and_then(ascii);
    let number = |tag: Tag| field(tag).and_then(|v| rational(v, 0));

    let gps = (|| {
        let mut latitude = dms_degrees(field(Tag::GPSLatitude)?)?;
        let mut longitude = dms_degrees(field(Tag::GPSLongitude)?)?;
        if text(Tag::GPSLatitudeRef).is_some_and(|r| r.eq_ignore_ascii_case("S")) {
            latitude = -latitude;
        }
        if text(Tag::GPSLongitudeRef).is_some_and(|r| r.eq_ignore_ascii_case("W")) {
            longitude = -longitude;
        }
        let below_sea =
            matches!(field(Tag::GPSAltitudeRef), Some(Value::Byte(b)) if b.first() == Some(&1));
        let altitude = number(Tag::GPSAltitude).map(|a| if below_sea { -a } else { a });
        // (0, 0) is what receivers without a fix write.
        let plausible = latitude.abs() <= 90.0
            && longitude.abs() <= 180.0
            && !(latitude == 0.0 && longitude == 0.0);
        plausible.then_some(GpsPosition {
            latitude,
            longitude,
            altitude,
        })
    })();

    let pixel_dimensions = match (number(Tag::PixelXDimension), number(Tag::PixelYDimension)) {
        (Some(w), Some(h)) if w > 0.0 && h > 0.0 => Some((w as u32, h as u32)),
        _ => None,
    };
    // FocalPlaneResolutionUnit: 2 = inch, 3 = cm, 4 = mm (EXIF 2.3 and common practice).
    let unit_mm = match number(Tag::FocalPlaneResolutionUnit).map(|u| u as u32) {
        Some(3) => Some(10.0),
        Some(4) => Some(1.0),
        Some(2) | None => Some(25.4),
        Some(_) => None,
    };
    let sensor_size_mm = match (
        number(Tag::FocalPlaneXResolution),
        number(Tag::FocalPlaneYResolution),
        pixel_dimensions,
        unit_mm,
    ) {
        (Some(rx), Some(ry), Some((w, h)), Some(unit)) if rx > 0.0 && ry > 0.0 => {
            Some((w as f64 / rx * unit, h as f64 / ry * unit))
        }
        _ => None,
    };

    Ok(ExifInfo {
        make: text(Tag::Make),
        model: text(Tag::Model),
        focal_length_mm: number(Tag::FocalLength).filter(|f| *f > 0.0),
        focal_length_35mm: number(Tag::FocalLengthIn35mmFilm).filter(|f| *f > 0.0),
        sensor_size_mm,
        pixel_dimensions,
        gps,
        timestamp: text(Tag::DateTimeOriginal).or_else(|| text(Tag::DateTime)),
    })
}

/// Camera tags to embed in a JPEG, as a camera writes them.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraTags {
    /// Maker.
    pub make: String,
    /// Model.
    pub model: String,
    /// 35 mm equivalent focal length, millimetres (an integer in EXIF).
    pub focal_length_35mm: u16,
}

/// A JPEG stream with an EXIF (APP1) segment holding `tags` inserted after its start-of-image
/// marker. `what` names the image in errors.
pub fn jpeg_with_camera_tags(
    jpeg: &[u8],
    tags: &CameraTags,
    what: &Path,
) -> Result<Vec<u8>, IoError> {
    use exif::Field;
    use exif::experimental::Writer;
    if jpeg.len() < 2 || jpeg[0] != 0xFF || jpeg[1] != 0xD8 {
        return Err(IoError::invalid(
            what,
            "not a JPEG stream (no start-of-image marker)",
        ));
    }
    let ascii = |tag: Tag, s: &str| Field {
        tag,
        ifd_num: In::PRIMARY,
        value: Value::Ascii(vec![s.as_bytes().to_vec()]),
    };
    let fields = [
        ascii(Tag::Make, &tags.make),
        ascii(Tag::Model, &tags.model),
        Field {
            tag: Tag::FocalLengthIn35mmFilm,
            ifd_num: In::PRIMARY,
            value: Value::Short(vec![tags.focal_length_35mm]),
        },
    ];
    let mut writer = Writer::new();
    for f in &fields {
        writer.push_field(f);
    }
    let mut tiff = std::io::Cursor::new(Vec::new());
    writer
        .write(&mut tiff, false)
        .map_err(|e| IoError::invalid(what, format!("cannot encode EXIF: {e}")))?;
    let tiff = tiff.into_inner();
    let length = u16::try_from(tiff.len() + 8)
        .map_err(|_| IoError::invalid(what, "EXIF block larger than a JPEG segment"))?;
    let mut out = Vec::with_capacity(jpeg.len() + tiff.len() + 10);
    out.extend_from_slice(&jpeg[..2]);
    out.extend_from_slice(&[0xFF, 0xE1]);
    out.extend_from_slice(&length.to_be_bytes());
    out.extend_from_slice(b"Exif\0\0");
    out.extend_from_slice(&tiff);
    out.extend_from_slice(&jpeg[2..]);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_tags_written_into_a_jpeg_read_back() {
        use image::ImageEncoder;
        let mut jpeg = std::io::Cursor::new(Vec::new());
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .write_image(&[128u8; 64 * 48], 64, 48, image::ExtendedColorType::L8)
            .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tagged.jpg");
        let tags = CameraTags {
            make: "timesift".into(),
            model: "synthetic".into(),
            focal_length_35mm: 26,
        };
        let tagged = jpeg_with_camera_tags(jpeg.get_ref(), &tags, &path).unwrap();
        std::fs::write(&path, &tagged).unwrap();
        let info = read_exif(&path).unwrap();
        assert_eq!(info.make.as_deref(), Some("timesift"));
        assert_eq!(info.focal_length_35mm, Some(26.0));
        let f = info.focal_length_px(64, 48).unwrap();
        assert!((f - 26.0 / 36.0 * 64.0).abs() < 1e-9, "{f}");
        assert_eq!(crate::image::dimensions(&path).unwrap(), (64, 48));
        let err = jpeg_with_camera_tags(b"PNG", &tags, &path)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("tagged.jpg") && err.contains("not a JPEG"),
            "{err}"
        );
    }
}
