//! The fuzz targets: one per reader, each handing bytes to the reader as timesift would.

use std::fmt;
use std::path::Path;

use timesift_features::text::DescriptorKind;
use timesift_io::exr as depth_maps;
use timesift_io::{
    bal, cameras_json, colmap, csv_inputs, exif, geotiff, image, libmv, ply, pointcloud, wkt,
};

use crate::scratch;

/// A reader under test.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Target {
    /// `project.toml`, validated against the example project's files (`Project::load`).
    ProjectToml,
    /// `gnss.csv`.
    GnssCsv,
    /// `gcps.csv` and `checkpoints.csv` (one format).
    GcpsCsv,
    /// `markers.csv`.
    MarkersCsv,
    /// `stable_points.csv`.
    StablePointsCsv,
    /// `scalebars.csv`.
    ScalebarsCsv,
    /// `fiducials.csv`.
    FiducialsCsv,
    /// `stable.csv` (`[name,]WKT` lines) and bare WKT.
    StableAreasWkt,
    /// `cameras.json`.
    CamerasJson,
    /// A COLMAP text model: `cameras.txt`, `images.txt` and `points3D.txt`, cut from one input
    /// at the lines `@@@@`.
    ColmapText,
    /// The binary feature files of `work/features`.
    FeaturesBin,
    /// The binary match files of `work/matches`.
    MatchesBin,
    /// The feature text format (`timesift features --out F.txt`), as SIFT and as LDB.
    FeaturesText,
    /// GeoTIFF, COG and BigTIFF: size and georeference, then the samples as f32, bands and RGB.
    Geotiff,
    /// LAS and LAZ through the `las` crate (every attribute).
    Las,
    /// LAS and LAZ through the chunked position reader (what gridding reads).
    LazPositions,
    /// The EXR depth and confidence maps of `work/dense`.
    Exr,
    /// EXIF in JPEG (focal length, camera, GPS).
    Exif,
    /// The binary PLY tie points of `work/align`.
    Ply,
    /// Bundle Adjustment in the Large problems.
    Bal,
    /// libmv bundle problems.
    Libmv,
    /// Image decoding (JPEG, PNG, TIFF) to grey.
    Image,
}

/// What a reader made of an input.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// Read without error.
    Accepted,
    /// Refused with this message.
    Refused(String),
}

impl Target {
    /// Every target, in the order tables list them.
    pub const ALL: [Target; 22] = [
        Target::ProjectToml,
        Target::GnssCsv,
        Target::GcpsCsv,
        Target::MarkersCsv,
        Target::StablePointsCsv,
        Target::ScalebarsCsv,
        Target::FiducialsCsv,
        Target::StableAreasWkt,
        Target::CamerasJson,
        Target::ColmapText,
        Target::FeaturesBin,
        Target::MatchesBin,
        Target::FeaturesText,
        Target::Geotiff,
        Target::Las,
        Target::LazPositions,
        Target::Exr,
        Target::Exif,
        Target::Ply,
        Target::Bal,
        Target::Libmv,
        Target::Image,
    ];

    /// The target's name: its fuzz target's, its corpus folder's.
    pub fn name(self) -> &'static str {
        match self {
            Target::ProjectToml => "project_toml",
            Target::GnssCsv => "gnss_csv",
            Target::GcpsCsv => "gcps_csv",
            Target::MarkersCsv => "markers_csv",
            Target::StablePointsCsv => "stable_points_csv",
            Target::ScalebarsCsv => "scalebars_csv",
            Target::FiducialsCsv => "fiducials_csv",
            Target::StableAreasWkt => "stable_areas_wkt",
            Target::CamerasJson => "cameras_json",
            Target::ColmapText => "colmap_text",
            Target::FeaturesBin => "features_bin",
            Target::MatchesBin => "matches_bin",
            Target::FeaturesText => "features_text",
            Target::Geotiff => "geotiff",
            Target::Las => "las",
            Target::LazPositions => "laz_positions",
            Target::Exr => "exr",
            Target::Exif => "exif",
            Target::Ply => "ply",
            Target::Bal => "bal",
            Target::Libmv => "libmv",
            Target::Image => "image",
        }
    }

    /// The target of a name, as [`Target::name`] spells it.
    pub fn from_name(name: &str) -> Option<Target> {
        Target::ALL.into_iter().find(|t| t.name() == name)
    }
}

impl fmt::Display for Target {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The line that cuts a COLMAP input into its three files.
pub const COLMAP_SEPARATOR: &[u8] = b"\n@@@@\n";

/// Hands `bytes` to the target's reader. A panic inside is a finding and propagates. A refusal
/// must be one line naming the file: one that is not is returned as a finding, `Err`.
pub fn run(target: Target, bytes: &[u8]) -> Result<Verdict, String> {
    let (verdict, folder) = if target == Target::ProjectToml {
        scratch::with_project(|dir| (read_project(dir, bytes), dir.to_path_buf()))
    } else {
        scratch::with_folder(|dir| (read(target, dir, bytes), dir.to_path_buf()))
    };
    match verdict {
        Ok(()) => Ok(Verdict::Accepted),
        Err(message) => {
            if message.contains('\n') {
                return Err(format!("a refusal of several lines: {message:?}"));
            }
            if !message.contains(&*folder.to_string_lossy()) {
                return Err(format!("a refusal naming no file: {message:?}"));
            }
            Ok(Verdict::Refused(message))
        }
    }
}

fn read_project(dir: &Path, bytes: &[u8]) -> Result<(), String> {
    scratch::put(dir, timesift::project::PROJECT_FILE, bytes);
    shown(timesift::Project::load(dir))
}

/// Reads `bytes` as the target's file(s) in `dir`; the refusal's message on error.
fn read(target: Target, dir: &Path, bytes: &[u8]) -> Result<(), String> {
    let put = |name: &str| scratch::put(dir, name, bytes);
    match target {
        Target::ProjectToml => read_project(dir, bytes),
        Target::GnssCsv => shown(csv_inputs::read_gnss(&put("gnss.csv"))),
        Target::GcpsCsv => {
            // Two readers of one file: accepted when one of them accepts it.
            let path = put("gcps.csv");
            let gcps = shown(csv_inputs::read_gcps(&path));
            gcps.or(shown(csv_inputs::read_checkpoints(&path)))
        }
        Target::MarkersCsv => shown(csv_inputs::read_markers(&put("markers.csv"))),
        Target::StablePointsCsv => shown(csv_inputs::read_stable_points(&put("stable_points.csv"))),
        Target::ScalebarsCsv => shown(csv_inputs::read_scale_bars(&put("scalebars.csv"))),
        Target::FiducialsCsv => shown(csv_inputs::read_fiducials(&put("fiducials.csv"))),
        Target::StableAreasWkt => {
            // Bare WKT through its parser (which names no file), then as a stable-area file.
            let _ = wkt::parse_polygons(&String::from_utf8_lossy(bytes));
            shown(csv_inputs::read_stable_areas(&put("stable.csv")))
        }
        Target::CamerasJson => shown(cameras_json::read_cameras_json(&put("cameras.json"))),
        Target::ColmapText => {
            let model = dir.join("sparse");
            let mut parts = split(bytes, COLMAP_SEPARATOR);
            for name in ["cameras.txt", "images.txt", "points3D.txt"] {
                if let Some(part) = parts.next() {
                    scratch::put(&model, name, part);
                }
            }
            shown(colmap::read_colmap_text(&model))
        }
        Target::FeaturesBin => shown(timesift_matching::storage::read_features(&put(
            "IMG_0001.features",
        ))),
        Target::MatchesBin => shown(timesift_matching::storage::read_matches(&put(
            "IMG_0001-IMG_0002.matches",
        ))),
        Target::FeaturesText => {
            // SIFT or LDB descriptors: accepted when read as one of them.
            let path = put("IMG_0001.sift.txt");
            let float = shown(timesift_features::text::read(&path, DescriptorKind::Float));
            float.or(shown(timesift_features::text::read(
                &path,
                DescriptorKind::Binary,
            )))
        }
        Target::Geotiff => {
            let path = put("dem.tif");
            shown(geotiff::read_grid(&path))?;
            // A DEM is read as f32, an orthomosaic as RGB, a stack as bands: each may refuse
            // what another accepts, and each must refuse it cleanly.
            let f32 = shown(geotiff::read_f32(&path));
            let bands = shown(geotiff::read_bands_f32(&path));
            let rgb = shown(geotiff::read_rgb8(&path));
            f32.or(bands).or(rgb)
        }
        Target::Las => shown(pointcloud::read_las(&put("dense.laz"))),
        Target::LazPositions => shown(pointcloud::read_las_positions(&put("dense.laz"))),
        Target::Exr => shown(depth_maps::read_f32_channels(&put("IMG_0001.depth.exr"))),
        Target::Exif => shown(exif::read_exif(&put("IMG_0001.jpg"))),
        Target::Ply => shown(ply::read_tiepoints(&put("tiepoints.ply"))),
        Target::Bal => shown(bal::read_bal(&put("problem.txt"))),
        Target::Libmv => shown(libmv::read_libmv(&put("problem.bin"))),
        Target::Image => shown(image::read_grey(&put("IMG_0001.jpg"))),
    }
}

/// A reader's result reduced to its message.
fn shown<T, E: fmt::Display>(result: Result<T, E>) -> Result<(), String> {
    result.map(|_| ()).map_err(|e| e.to_string())
}

/// The pieces of `bytes` between occurrences of `separator`.
fn split<'a>(bytes: &'a [u8], separator: &'a [u8]) -> impl Iterator<Item = &'a [u8]> + 'a {
    let mut rest = Some(bytes);
    std::iter::from_fn(move || {
        let now = rest?;
        match now.windows(separator.len()).position(|w| w == separator) {
            Some(at) => {
                rest = Some(&now[at + separator.len()..]);
                Some(&now[..at])
            }
            None => {
                rest = None;
                Some(now)
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for t in Target::ALL {
            assert_eq!(Target::from_name(t.name()), Some(t));
        }
        assert_eq!(Target::from_name("nothing"), None);
    }

    #[test]
    fn colmap_inputs_split_at_the_separator() {
        let pieces: Vec<&[u8]> = split(b"a\n@@@@\nb\n@@@@\n", COLMAP_SEPARATOR).collect();
        assert_eq!(pieces, vec![&b"a"[..], b"b", b""]);
        let whole: Vec<&[u8]> = split(b"abc", COLMAP_SEPARATOR).collect();
        assert_eq!(whole, vec![&b"abc"[..]]);
    }
}
