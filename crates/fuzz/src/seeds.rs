//! The seed corpus: small valid inputs of every target, made by timesift's own writers and cut
//! from the real files in `../shared/data` and `data/example`. `cargo xtask fuzz --seed` writes
//! them under `fuzz/corpus/<target>/`, named by content; the fuzzers grow the corpus from there.
//!
//! Seeds are kept small (a few kilobytes): a fuzzer's speed falls with the input's size, and the
//! corpus is committed.

use std::path::Path;

use nalgebra::Vector3;
use timesift_core::features::{Descriptors, Keypoint};
use timesift_io::coords::Crs;
use timesift_io::exr as depth_maps;
use timesift_io::geotiff::{GeoRaster, GeoReference, GeoTransform};
use timesift_io::pointcloud::{AttributeValues, ExtraAttribute, LasWriteOptions, PointCloud};
use timesift_io::{cameras_json, colmap, geotiff, ply, pointcloud};
use timesift_matching::Match;

use crate::Target;
use crate::targets::COLMAP_SEPARATOR;

/// The end of the name of a seed that belongs to another project's files (a `project.toml`
/// naming images the example does not have): read in full, then refused over those files.
pub const ELSEWHERE: &str = "-elsewhere";

/// A seed: a name saying what it is, and its bytes.
pub type Seed = (String, Vec<u8>);

/// The seeds of `target`. `shared_data` is `../shared/data`; `workspace` the repository root.
/// Writing through timesift's writers needs a scratch folder: `scratch`.
pub fn seeds(
    target: Target,
    workspace: &Path,
    shared_data: &Path,
    scratch: &Path,
) -> Result<Vec<Seed>, String> {
    let example = workspace.join("data/example");
    let file = |path: &Path| -> Result<Vec<u8>, String> {
        std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))
    };
    let text = |name: &str, s: &str| -> Seed { (name.to_string(), s.as_bytes().to_vec()) };
    let mar = shared_data.join("rendered-mar");
    Ok(match target {
        Target::ProjectToml => vec![
            (
                format!("rendered-mar{ELSEWHERE}"),
                file(&mar.join("project.toml"))?,
            ),
            ("example".into(), example_project(&example, scratch)?),
        ],
        Target::GnssCsv => vec![
            ("example".into(), file(&example.join("gnss.csv"))?),
            (
                "rendered-mar".into(),
                head(&file(&mar.join("gnss.csv"))?, 12),
            ),
        ],
        Target::GcpsCsv => vec![
            ("example".into(), file(&example.join("gcps.csv"))?),
            ("rendered-mar".into(), file(&mar.join("gcps.csv"))?),
            ("checkpoints".into(), file(&mar.join("checkpoints.csv"))?),
        ],
        Target::MarkersCsv => vec![
            ("example".into(), file(&example.join("markers.csv"))?),
            (
                "rendered-mar".into(),
                head(&file(&mar.join("markers.csv"))?, 16),
            ),
        ],
        Target::StablePointsCsv => vec![text("points", STABLE_POINTS)],
        Target::ScalebarsCsv => vec![text("bars", SCALE_BARS)],
        Target::FiducialsCsv => vec![text("marks", FIDUCIALS)],
        Target::StableAreasWkt => vec![
            ("example".into(), file(&example.join("stable.csv"))?),
            text("multipolygon", STABLE_MULTIPOLYGON),
        ],
        Target::CamerasJson => vec![("synthetic".into(), cameras_json_seed(scratch)?)],
        Target::ColmapText => vec![("synthetic".into(), colmap_seed(scratch)?)],
        Target::FeaturesBin => vec![
            ("sift".into(), features_seed(scratch, false)?),
            ("ldb".into(), features_seed(scratch, true)?),
        ],
        Target::MatchesBin => vec![("matches".into(), matches_seed(scratch)?)],
        Target::FeaturesText => vec![
            ("sift".into(), features_text_seed(scratch, false)?),
            ("ldb".into(), features_text_seed(scratch, true)?),
        ],
        Target::Geotiff => vec![
            ("dem".into(), dem_seed(scratch, false)?),
            ("dem-bigtiff".into(), dem_seed(scratch, true)?),
            ("ortho".into(), ortho_seed(scratch)?),
            ("mask".into(), file(&mar.join("truth/common_valid.tif"))?),
        ],
        Target::Las | Target::LazPositions => vec![
            ("dense-laz".into(), cloud_seed(scratch, "dense.laz")?),
            ("dense-las".into(), cloud_seed(scratch, "dense.las")?),
        ],
        Target::Exr => vec![("depth".into(), exr_seed(scratch)?)],
        Target::Exif => vec![(
            "lund-01".into(),
            jpeg_header(&file(&shared_data.join("opensfm/lund/images/01.jpg"))?),
        )],
        Target::Ply => vec![("tiepoints".into(), ply_seed(scratch)?)],
        Target::Bal => vec![text("two-cameras", BAL_PROBLEM)],
        Target::Libmv => vec![("two-cameras".into(), libmv_seed())],
        Target::Image => vec![
            (
                "png".into(),
                file(&example.join("images/2018-06/IMG_0001.png"))?,
            ),
            ("jpeg".into(), small_jpeg()?),
        ],
    })
}

/// The `project.toml` that `timesift init` writes for the example project, with its inputs.
fn example_project(example: &Path, scratch: &Path) -> Result<Vec<u8>, String> {
    let dir = scratch.join("example");
    let _ = std::fs::remove_dir_all(&dir);
    copy_tree(example, &dir).map_err(|e| format!("{}: {e}", example.display()))?;
    timesift::commands::init::init(
        &dir,
        timesift::commands::init::InitOptions { overwrite: true },
    )
    .map_err(|e| e.to_string())?;
    let toml = dir.join(timesift::project::PROJECT_FILE);
    let bytes = std::fs::read(&toml).map_err(|e| format!("{}: {e}", toml.display()))?;
    let _ = std::fs::remove_dir_all(&dir);
    Ok(bytes)
}

fn copy_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(to)?;
    for entry in std::fs::read_dir(from)? {
        let entry = entry?;
        let target = to.join(entry.file_name());
        if entry.file_type()?.is_dir() {
            copy_tree(&entry.path(), &target)?;
        } else {
            std::fs::copy(entry.path(), target)?;
        }
    }
    Ok(())
}

/// The first `lines` lines of a text file.
fn head(bytes: &[u8], lines: usize) -> Vec<u8> {
    let end = bytes
        .iter()
        .enumerate()
        .filter(|(_, b)| **b == b'\n')
        .nth(lines - 1)
        .map_or(bytes.len(), |(i, _)| i + 1);
    bytes[..end].to_vec()
}

/// A JPEG's segments up to its first scan: where EXIF lives, without the compressed image.
fn jpeg_header(jpeg: &[u8]) -> Vec<u8> {
    let mut at = 2;
    while at + 4 <= jpeg.len() && jpeg[at] == 0xFF && jpeg[at + 1] != 0xDA {
        let len = usize::from(u16::from_be_bytes([jpeg[at + 2], jpeg[at + 3]]));
        at += 2 + len;
    }
    jpeg[..at.min(jpeg.len())].to_vec()
}

/// What a writer wrote to `scratch/name`.
fn written<E: std::fmt::Display>(
    scratch: &Path,
    name: &str,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<Vec<u8>, String> {
    let path = scratch.join(name);
    write(&path).map_err(|e| e.to_string())?;
    let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let _ = std::fs::remove_file(&path);
    Ok(bytes)
}

fn small_jpeg() -> Result<Vec<u8>, String> {
    let img = image::RgbImage::from_fn(24, 16, |x, y| {
        image::Rgb([(x * 10) as u8, (y * 15) as u8, 90])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg)
        .map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

fn georef() -> GeoReference {
    GeoReference {
        transform: GeoTransform {
            origin_x: 500_000.0,
            origin_y: 4_000_100.0,
            pixel_width: 0.5,
            pixel_height: -0.5,
        },
        crs: Crs::Epsg(32632),
        nodata: Some(-9999.0),
        pixel_is_point: false,
    }
}

fn dem_seed(scratch: &Path, big: bool) -> Result<Vec<u8>, String> {
    let (width, height) = (12, 9);
    let data: Vec<f32> = (0..width * height)
        .map(|i| {
            if i % 17 == 0 {
                -9999.0
            } else {
                100.0 + i as f32 * 0.25
            }
        })
        .collect();
    let raster = GeoRaster {
        width,
        height,
        bands: 1,
        data,
        georef: georef(),
    };
    if !big {
        return written(scratch, "dem.tif", |p| geotiff::write_f32(p, &raster));
    }
    written(scratch, "dem.tif", |p| {
        let mut w = geotiff::GeoTiffWriter::create(
            p,
            raster.width,
            raster.height,
            timesift_io::tiled_tiff::SampleFormat::F32 {
                nodata: Some(-9999.0),
            },
            &raster.georef,
        )?
        .big_tiff();
        w.push_rows(timesift_io::tiled_tiff::Pixels::F32 {
            data: &raster.data,
            nodata: Some(-9999.0),
        })?;
        w.finish()
    })
}

fn ortho_seed(scratch: &Path) -> Result<Vec<u8>, String> {
    let (width, height) = (10, 8);
    let data: Vec<u8> = (0..width * height * 3)
        .map(|i| (i * 7 % 251) as u8)
        .collect();
    let raster = GeoRaster {
        width,
        height,
        bands: 3,
        data,
        georef: GeoReference {
            nodata: None,
            ..georef()
        },
    };
    written(scratch, "ortho.tif", |p| geotiff::write_rgb8(p, &raster))
}

fn cloud_seed(scratch: &Path, name: &str) -> Result<Vec<u8>, String> {
    let n = 40;
    let positions: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let f = i as f64;
            [
                500_000.0 + f * 0.37,
                4_000_000.0 + (f * 0.91) % 7.0,
                50.0 + (f * 0.13).sin(),
            ]
        })
        .collect();
    let cloud = PointCloud {
        colors: Some(
            (0..n)
                .map(|i| [i as u16 * 1000, 30_000, 65_535 - i as u16])
                .collect(),
        ),
        attributes: vec![
            ExtraAttribute {
                name: "confidence".into(),
                values: AttributeValues::F32((0..n).map(|i| i as f32 / n as f32).collect()),
            },
            ExtraAttribute {
                name: "views".into(),
                values: AttributeValues::U8((0..n).map(|i| (i % 5) as u8 + 2).collect()),
            },
        ],
        positions,
        crs: Crs::Epsg(32632),
    };
    written(scratch, name, |p| {
        pointcloud::write_las(p, &cloud, &LasWriteOptions::default())
    })
}

fn exr_seed(scratch: &Path) -> Result<Vec<u8>, String> {
    let (w, h) = (8, 6);
    let depth: Vec<f32> = (0..w * h).map(|i| 10.0 + i as f32 * 0.1).collect();
    let conf: Vec<f32> = (0..w * h).map(|i| (i % 7) as f32 / 7.0).collect();
    written(scratch, "depth.exr", |p| {
        depth_maps::write_f32_channels(p, w, h, &[("depth", &depth), ("confidence", &conf)])
    })
}

fn keypoints(n: usize) -> Vec<Keypoint> {
    (0..n)
        .map(|i| Keypoint {
            x: 10.5 + i as f64 * 3.0,
            y: 20.25 + (i * 7 % 11) as f64,
            scale: 1.6 + i as f64 * 0.1,
            orientation: i as f64 * 0.3,
            response: 0.01 * i as f32,
            octave: (i % 3) as i16,
        })
        .collect()
}

fn features_seed(scratch: &Path, binary: bool) -> Result<Vec<u8>, String> {
    let n = 6;
    let descriptors = if binary {
        Descriptors::Binary {
            bytes: 8,
            data: (0..n * 8).map(|i| (i * 37 % 256) as u8).collect(),
        }
    } else {
        Descriptors::Float {
            dim: 8,
            data: (0..n * 8).map(|i| (i % 9) as f32 / 9.0).collect(),
        }
    };
    written(scratch, "a.features", |p| {
        timesift_matching::storage::write_features(p, &keypoints(n), &descriptors)
    })
}

fn features_text_seed(scratch: &Path, binary: bool) -> Result<Vec<u8>, String> {
    let n = 4;
    let descriptors = if binary {
        Descriptors::Binary {
            bytes: 4,
            data: (0..n * 4).map(|i| (i * 53 % 256) as u8).collect(),
        }
    } else {
        Descriptors::Float {
            dim: 4,
            data: (0..n * 4).map(|i| (i % 5) as f32 / 5.0).collect(),
        }
    };
    let features = timesift_features::Features {
        keypoints: keypoints(n),
        descriptors,
    };
    written(scratch, "a.sift.txt", |p| {
        timesift_features::text::write(p, &features)
    })
}

fn matches_seed(scratch: &Path) -> Result<Vec<u8>, String> {
    let matches: Vec<Match> = (0..5)
        .map(|i| Match {
            query: i,
            train: 4 - i,
            distance: 0.1 * i as f32,
        })
        .collect();
    written(scratch, "a.matches", |p| {
        timesift_matching::storage::write_matches(p, &matches)
    })
}

fn ply_seed(scratch: &Path) -> Result<Vec<u8>, String> {
    let epochs = vec!["2018".to_string(), "2019".to_string(), "2020".to_string()];
    let points: Vec<ply::TiePoint> = (0..5)
        .map(|i| {
            let mut epochs = ply::EpochSet::only(i % 3);
            epochs.insert((i + 1) % 3);
            ply::TiePoint {
                position: Vector3::new(i as f64, 2.0 * i as f64, 50.0),
                observations: 2 + i as u16,
                epochs,
            }
        })
        .collect();
    written(scratch, "tiepoints.ply", |p| {
        ply::write_tiepoints(p, &epochs, &points)
    })
}

fn cameras_json_seed(scratch: &Path) -> Result<Vec<u8>, String> {
    let json = written(scratch, "cameras.json", |p| {
        std::fs::write(p, CAMERAS_JSON).map_err(|e| e.to_string())
    })?;
    // Through the reader and writer, so that the seed is what timesift itself writes.
    let path = scratch.join("in.json");
    std::fs::write(&path, &json).map_err(|e| e.to_string())?;
    let reconstruction = cameras_json::read_cameras_json(&path).map_err(|e| e.to_string())?;
    written(scratch, "cameras.json", |p| {
        cameras_json::write_cameras_json(p, &reconstruction)
    })
}

fn colmap_seed(scratch: &Path) -> Result<Vec<u8>, String> {
    let path = scratch.join("in.json");
    std::fs::write(&path, CAMERAS_JSON).map_err(|e| e.to_string())?;
    let reconstruction = cameras_json::read_cameras_json(&path).map_err(|e| e.to_string())?;
    let model = colmap::from_reconstruction(&reconstruction)?;
    let dir = scratch.join("colmap");
    colmap::write_colmap_text(&dir, &model).map_err(|e| e.to_string())?;
    let mut out = Vec::new();
    for (k, name) in ["cameras.txt", "images.txt", "points3D.txt"]
        .iter()
        .enumerate()
    {
        if k > 0 {
            out.extend_from_slice(COLMAP_SEPARATOR);
        }
        let path = dir.join(name);
        out.extend(std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?);
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(out)
}

fn libmv_seed() -> Vec<u8> {
    let mut out = b"vP".to_vec();
    let real = |out: &mut Vec<u8>, v: f32| out.extend_from_slice(&v.to_le_bytes());
    let int = |out: &mut Vec<u8>, v: i32| out.extend_from_slice(&v.to_le_bytes());
    for v in [1000.0, 1000.0, 320.0, 240.0, 0.01, -0.002, 0.0, 0.0] {
        real(&mut out, v);
    }
    int(&mut out, 2);
    for camera in 0..2 {
        int(&mut out, camera);
        for k in 0..9 {
            real(&mut out, if k % 4 == 0 { 1.0 } else { 0.0 });
        }
        for v in [camera as f32, 0.0, 0.0] {
            real(&mut out, v);
        }
    }
    int(&mut out, 2);
    for track in 0..2 {
        int(&mut out, track);
        for v in [track as f32, 1.0, 10.0] {
            real(&mut out, v);
        }
    }
    int(&mut out, 4);
    for (image, track) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
        int(&mut out, image);
        int(&mut out, track);
        real(&mut out, 300.0 + 10.0 * track as f32);
        real(&mut out, 200.0 + 5.0 * image as f32);
    }
    out
}

const STABLE_POINTS: &str = "name,sxy,sz\nrock1,0.02,0.03\nrock2\n# a comment\nbridge,0.01,0.01\n";

const SCALE_BARS: &str = "a,b,distance,sd\nT1,T2,0.5,0.0005\nT2,T3,1.0,0.001\n";

const FIDUCIALS: &str = "image,mark,u,v\n\
images/1971/scan_001.tif,1,120.5,130.0\n\
images/1971/scan_001.tif,2,11880.0,131.5\n\
images/1971/scan_001.tif,3,11879.0,11870.25\n";

const STABLE_MULTIPOLYGON: &str = "name,wkt\n\
quarry,\"MULTIPOLYGON (((0 0, 10 0, 10 10, 0 10, 0 0), (2 2, 3 2, 3 3, 2 2)), ((20 20, 30 20, 30 30, 20 20)))\"\n\
POLYGON ((40 40, 50 40, 50 50, 40 40))\n";

const BAL_PROBLEM: &str = "2 2 4\n\
0 0 -10.5 3.25\n0 1 12.0 -4.5\n1 0 -8.0 2.0\n1 1 14.5 -3.0\n\
0.01 0.02 0.0 0.1 0.0 -5.0 1000.0 0.01 -0.001\n\
0.0 -0.01 0.02 0.3 0.1 -5.2 1000.0 0.01 -0.001\n\
0.5 0.2 1.0\n-0.4 0.3 1.1\n";

const CAMERAS_JSON: &str = r#"{
  "crs": "EPSG:32632",
  "cameras": {
    "c1": {"model": "brown", "width": 64, "height": 48, "f": 60.0, "cx": 0.0, "cy": 0.0,
           "k1": 0.01, "k2": 0.0, "k3": 0.0, "p1": 0.0, "p2": 0.0, "b1": 0.0, "b2": 0.0}
  },
  "images": [
    {"name": "images/2018-06/IMG_0001.png", "camera": "c1", "epoch": "2018-06",
     "R": [[1,0,0],[0,-1,0],[0,0,-1]], "t": [-100.0, 200.0, 60.0]},
    {"name": "images/2019-03/IMG_0001.png", "camera": "c1", "epoch": "2019-03",
     "R": [[1,0,0],[0,-1,0],[0,0,-1]], "t": [-102.0, 200.0, 60.0]}
  ]
}
"#;
