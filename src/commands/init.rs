//! `timesift init`: a `project.toml` from the folders of `images/` and the images' EXIF.

use std::fmt::Write as _;
use std::path::Path;

use timesift_io::coords::{Crs, utm_epsg_for};
use timesift_io::{exif, fsutil};

use crate::config::ProjectConfig;
use crate::project::{IMAGE_EXTENSIONS, PROJECT_FILE};
use crate::{Project, ProjectError};

/// Options of `timesift init`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InitOptions {
    /// Overwrite an existing `project.toml`.
    pub overwrite: bool,
}

/// What `init` found and wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct InitSummary {
    /// Epoch names and image counts.
    pub epochs: Vec<(String, usize)>,
    /// The CRS chosen.
    pub crs: Crs,
    /// Images with an EXIF GPS position.
    pub images_with_gps: usize,
}

fn toml_string(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}

/// Scans `dir/images/<epoch>/`, reads EXIF, chooses the CRS (the UTM zone of the mean GPS position,
/// or `local` without GPS), validates the result like `timesift run` would, and writes
/// `project.toml` atomically.
pub fn init(dir: &Path, options: InitOptions) -> Result<InitSummary, ProjectError> {
    let config_path = dir.join(PROJECT_FILE);
    if config_path.exists() && !options.overwrite {
        return Err(ProjectError::Path {
            path: config_path,
            message: "already exists (use --force to overwrite)".to_string(),
        });
    }
    let found = epoch_folders(dir)?;
    let text = project_toml(&found);
    let config = ProjectConfig::parse(&config_path, &text)?;
    Project::from_config(dir, config)?;
    fsutil::write_bytes_atomically(&config_path, text.as_bytes())?;
    Ok(InitSummary {
        epochs: found.epochs,
        crs: found.crs,
        images_with_gps: found.with_gps,
    })
}

/// The epochs `images/` holds (a folder with images each, sorted) and the frame their EXIF GPS
/// suggests.
struct EpochFolders {
    /// Name and image count of each epoch.
    epochs: Vec<(String, usize)>,
    crs: Crs,
    with_gps: usize,
}

/// The epoch folders of `dir/images`, with the UTM zone of the images' mean EXIF GPS position
/// (a local frame without GPS).
fn epoch_folders(dir: &Path) -> Result<EpochFolders, ProjectError> {
    let images_dir = dir.join("images");
    let entries = std::fs::read_dir(&images_dir).map_err(|e| ProjectError::Path {
        path: images_dir.clone(),
        message: format!("cannot list the epoch folders: {e}"),
    })?;
    let mut epoch_dirs: Vec<_> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .collect();
    epoch_dirs.sort();
    let mut epochs = Vec::new();
    // Longitudes are averaged on the circle, so blocks across ±180° get the right zone.
    let (mut lat_sum, mut lon_sin, mut lon_cos, mut with_gps) = (0.0, 0.0, 0.0, 0usize);
    for epoch_dir in &epoch_dirs {
        let mut files: Vec<_> = std::fs::read_dir(epoch_dir)
            .map_err(|e| ProjectError::Path {
                path: epoch_dir.clone(),
                message: e.to_string(),
            })?
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| {
                p.is_file()
                    && p.extension()
                        .map(|e| e.to_string_lossy().to_ascii_lowercase())
                        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.as_str()))
            })
            .collect();
        if files.is_empty() {
            continue;
        }
        files.sort();
        for f in &files {
            if let Some(gps) = exif::read_exif(f)?.gps {
                lat_sum += gps.latitude;
                lon_sin += gps.longitude.to_radians().sin();
                lon_cos += gps.longitude.to_radians().cos();
                with_gps += 1;
            }
        }
        let name = epoch_dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        epochs.push((name, files.len()));
    }
    if epochs.is_empty() {
        return Err(ProjectError::Path {
            path: images_dir,
            message: "no epoch folder with images (expected images/<epoch>/*.jpg|png|tif)"
                .to_string(),
        });
    }
    let crs = if with_gps > 0 {
        Crs::Epsg(utm_epsg_for(
            lat_sum / with_gps as f64,
            lon_sin.atan2(lon_cos).to_degrees(),
        ))
    } else {
        Crs::Local
    };

    Ok(EpochFolders {
        epochs,
        crs,
        with_gps,
    })
}

/// `project.toml` for the epochs found: every epoch, and every section's keys commented with
/// their defaults.
fn project_toml(found: &EpochFolders) -> String {
    let (crs, with_gps, epochs) = (&found.crs, found.with_gps, &found.epochs);
    let reference = &epochs[0].0;
    let mut text = String::new();
    let _ = writeln!(
        text,
        "# timesift project written by `timesift init`. Commented keys show their defaults."
    );
    let _ = writeln!(
        text,
        "crs = {}  # {}\n",
        toml_string(&crs.to_string()),
        if with_gps > 0 {
            "UTM zone of the images' mean EXIF GPS position"
        } else {
            "no EXIF GPS found: a local frame"
        }
    );
    for (name, _) in epochs {
        let _ = writeln!(text, "[[epoch]]\nname = {}", toml_string(name));
        let _ = writeln!(
            text,
            "images = {}",
            toml_string(&format!("images/{}/*", glob::Pattern::escape(name)))
        );
        let _ = writeln!(
            text,
            "# camera = {}  # camera group sharing intrinsics\n",
            toml_string(name)
        );
    }
    align_section(&mut text, reference);
    dense_section(&mut text);
    raster_section(&mut text);
    cluster_section(&mut text);
    gnss_section(&mut text);
    camera_example(&mut text, reference);
    text
}

/// The `[align]` section, with `reference` as the reference epoch.
fn align_section(text: &mut String, reference: &str) {
    let _ = writeln!(text, "[align]");
    let _ = writeln!(
        text,
        "method = \"{}\"  # {}",
        timesift_align::Method::default(),
        timesift_align::Method::names(" | ")
    );
    let _ = writeln!(text, "reference_epoch = {}", toml_string(reference));
    let _ = writeln!(text, "features = \"sift\"  # sift | ldb");
    let _ = writeln!(
        text,
        "# pair_selection = \"auto\"  # auto | exhaustive | preselect (large blocks without priors)"
    );
    let _ = writeln!(
        text,
        "# epoch_partners = 2  # epochs matched either side of each, and the reference (default: all up to 8 epochs, then 2)"
    );
    let _ = writeln!(
        text,
        "# mapper = \"auto\"  # auto (global from 200 images) | incremental | global (rotation averaging and GNSS-seeded centres: faster on large blocks; needs priors)"
    );
    let _ = writeln!(text, "# max_keypoints = 40000");
    let _ = writeln!(
        text,
        "# coarse_match_keypoints = 1024  # largest-scale keypoints matched first; the rest guided by the geometry they verify (0: every pair exhaustively)"
    );
    let _ = writeln!(text, "# tie_point_accuracy_px = 1.0");
    let _ = writeln!(text, "# marker_accuracy_px = 0.5");
    let _ = writeln!(text, "# gcps_in_all_epochs = false");
    let _ = writeln!(
        text,
        "# inter_epoch_ties = \"auto\"  # with stable.csv only ties on it join the epochs; without, none on ground the ties show changed (\"stable\": stable.csv only; \"all\")"
    );
    let _ = writeln!(
        text,
        "# join_epoch_ties = false  # true: after the first block, join two epochs' tie points that it puts together and whose descriptors match; orient again (twice the time)"
    );
    let _ = writeln!(
        text,
        "# surface_ties = true  # hold the later epochs' tie points on stable ground to the reference epoch's surface (false: ties by features alone)"
    );
    let _ = writeln!(
        text,
        "# self_calibration = [\"f\", \"cx\", \"cy\", \"k1\", \"k2\", \"k3\", \"p1\", \"p2\"]  # intrinsics the final adjustments estimate (also b1, b2, k4)\n"
    );
}

/// The `[dense]` section, its keys at their defaults.
fn dense_section(text: &mut String) {
    let _ = writeln!(text, "[dense]");
    let _ = writeln!(
        text,
        "# level = 2            # 1 full resolution, 2 half (default), 4, 8"
    );
    let _ = writeln!(
        text,
        "# refine = true        # match again at twice the resolution where the level matches poorly (crowns, boulders, edges)"
    );
    let _ = writeln!(text, "# max_sources = 8      # source views per image");
    let _ = writeln!(
        text,
        "# min_views = 2        # sources that must agree with a depth"
    );
    let _ = writeln!(text, "# min_images = 3       # images per fused point");
    let _ = writeln!(
        text,
        "# fill_edges = false   # true: where only two views have a point in their field (edges), points from both"
    );
    let _ = writeln!(
        text,
        "# window_radius = 5    # matching window half-size, pixels"
    );
    let _ = writeln!(
        text,
        "# sigma_color = 0.04   # intensity σ of the window's bilateral weights (0-1);"
    );
    let _ = writeln!(
        text,
        "#                      # default 0.04 for digital images, 0.1 for film scans"
    );
    let _ = writeln!(
        text,
        "# iterations = 3       # PatchMatch iterations per pass"
    );
    let _ = writeln!(text, "# geometric_iterations = 2");
    let _ = writeln!(
        text,
        "# max_cost = 0.6       # largest 1 - NCC of a kept depth (film scans: 0.75)"
    );
    let _ = writeln!(
        text,
        "# black_is_nodata = true  # pure black pixels (scan borders) give no depth\n"
    );
}

/// The `[cluster]` section, its keys at their defaults.
fn cluster_section(text: &mut String) {
    let _ = writeln!(
        text,
        "[cluster]  # timesift run --executor slurm (the command line's options of the same names win)"
    );
    let _ = writeln!(
        text,
        "# partition = \"batch\"     # default: the cluster's default"
    );
    let _ = writeln!(
        text,
        "# account = \"geo\"         # default: your default account"
    );
    let _ = writeln!(
        text,
        "# time = \"04:00:00\"       # per task; default: the partition's limit"
    );
    let _ = writeln!(text, "# cpus_per_task = 4        # threads of one task");
    let _ = writeln!(
        text,
        "# max_array = 50           # most tasks of one array at once (default: no limit)"
    );
    let _ = writeln!(
        text,
        "# sbatch_args = [\"--qos=long\"]  # added to every sbatch"
    );
    let _ = writeln!(
        text,
        "# retries = 2              # times a failed task requeues itself"
    );
    let _ = writeln!(text, "# images_per_task = 40     # features");
    let _ = writeln!(text, "# pairs_per_task = 2000    # match");
    let _ = writeln!(text, "# views_per_task = 8       # each dense pass");
    let _ = writeln!(
        text,
        "# ortho_megapixels_per_task = 100.0  # ortho (rows of tiles of every epoch's mosaic)\n"
    );
}

/// The `[raster]` section, its keys at their defaults.
fn raster_section(text: &mut String) {
    let _ = writeln!(text, "[raster]");
    let _ = writeln!(
        text,
        "# dem_cell = \"auto\"      # m; auto = 2 x the coarsest epoch's GSD, rounded"
    );
    let _ = writeln!(
        text,
        "# ortho_cell = \"auto\"    # m; auto = the finest GSD, dividing dem_cell"
    );
    let _ = writeln!(
        text,
        "# extent = \"union\"       # union | intersection | [xmin, ymin, xmax, ymax]"
    );
    let _ = writeln!(
        text,
        "# dem_method = \"median\"  # median | max (surface of tall objects) | idw"
    );
    let _ = writeln!(
        text,
        "# idw_radius = 1.5       # idw search radius, DEM cells"
    );
    let _ = writeln!(text, "# min_points = 1         # points a DEM cell needs");
    let _ = writeln!(
        text,
        "# max_gap = 4            # holes up to this many cells are interpolated"
    );
    let _ = writeln!(
        text,
        "# feather = 2            # ortho seam blending, DEM cells"
    );
    let _ = writeln!(
        text,
        "# seam_sweeps = 3        # moves seams to where the images agree"
    );
    let _ = writeln!(
        text,
        "# gain_compensation = true  # per-image gains from the overlaps\n"
    );
}

/// The `[gnss]` section, its keys at their defaults.
fn gnss_section(text: &mut String) {
    let _ = writeln!(text, "[gnss]");
    let _ = writeln!(
        text,
        "# exif = true  # EXIF GPS as camera-centre priors when gnss.csv is absent"
    );
    let _ = writeln!(
        text,
        "# sxy = 5.0    # default horizontal standard deviation of priors, m"
    );
    let _ = writeln!(
        text,
        "# sz = 10.0    # default vertical standard deviation of priors, m"
    );
    let _ = writeln!(
        text,
        "# offsets = \"epoch\"  # a GNSS offset per epoch estimated in the block, or \"none\""
    );
    let _ = writeln!(
        text,
        "# weigh_by_scatter = \"controlled\"  # flights weighed by their scatter: \"controlled\" (those with control points), \"all\" or \"none\""
    );
}

/// A commented `[[camera]]` example naming `reference`.
fn camera_example(text: &mut String, reference: &str) {
    let _ = writeln!(
        text,
        "\n# A known calibration (e.g. a film camera's certificate and the scan resolution):\n\
         # [[camera]]\n\
         # name = {}      # camera group\n\
         # focal_mm = 152.06  # with pixel_mm; or focal_px = ...\n\
         # pixel_mm = 0.021\n\
         # adjust_focal = false  # true: nominal, refined where the georeferenced block determines it\n\
         # Scanned film (see `timesift fiducials`): the certificate's marks make the images scans.\n\
         # principal_point_mm = [0.004, -0.011]  # default: the centre of the marks\n\
         # distortion_um = [[0, 0], [40, 2], [80, -1], [120, -2]]  # certificate: r mm, Δr µm; held\n\
         # fiducial_template = \"calibration/mark.png\"  # one mark cut from a scan, centred\n\
         # interior_orientation = \"affine\"  # or \"projective\" (eight marks or more)\n\
         # mask = \"calibration/mask.png\"  # zero where no keypoint or depth may come from\n\
         # [camera.fiducials]  # mm, x right, y up\n\
         # TL = [-106.004, 105.996]",
        toml_string(reference)
    );
}
