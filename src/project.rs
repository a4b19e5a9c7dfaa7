//! A loaded and validated project directory: epochs with their images, camera groups, and the CSV
//! inputs cross-checked against each other.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use timesift_core::{EpochId, ImageId};
use timesift_io::coords::{Crs, Projector};
use timesift_io::csv_inputs::{self, ControlPoint, GnssPrior, Marker, ScaleBarInput, StableArea};
use timesift_io::exif;

use crate::ProjectError;
use crate::config::{EpochConfig, InputsConfig, ProjectConfig};

/// File name of the configuration inside a project directory.
pub const PROJECT_FILE: &str = "project.toml";

/// Extensions (lower case) of the images a glob selects.
pub const IMAGE_EXTENSIONS: [&str; 5] = ["jpg", "jpeg", "png", "tif", "tiff"];

/// An epoch of the project.
#[derive(Debug, Clone, PartialEq)]
pub struct Epoch {
    /// Name from `project.toml`.
    pub name: String,
    /// Camera group of its images.
    pub camera_group: String,
    /// Its images, in path order.
    pub images: Vec<ImageId>,
}

/// An image of the project.
#[derive(Debug, Clone, PartialEq)]
pub struct ProjectImage {
    /// Path relative to the project directory, with `/` separators.
    pub name: String,
    /// Its epoch.
    pub epoch: EpochId,
}

/// Where a camera-centre prior came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PriorSource {
    /// The gnss CSV file.
    GnssFile,
    /// EXIF GPS projected into the project CRS.
    Exif,
}

/// A camera-centre prior in the project CRS.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPrior {
    /// Camera centre (E, N, H), metres.
    pub position: Vector3<f64>,
    /// Horizontal standard deviation, metres.
    pub sxy: f64,
    /// Vertical standard deviation, metres.
    pub sz: f64,
    /// Origin of the prior.
    pub source: PriorSource,
}

/// A validated project.
#[derive(Debug, Clone)]
pub struct Project {
    /// The project directory.
    pub dir: PathBuf,
    /// The configuration as read.
    pub config: ProjectConfig,
    /// The world frame.
    pub crs: Crs,
    /// Epochs in configuration order.
    pub epochs: Vec<Epoch>,
    /// All images, indexed by [`ImageId`].
    pub images: Vec<ProjectImage>,
    /// Index of the reference epoch.
    pub reference_epoch: EpochId,
    /// Ground control points.
    pub gcps: Vec<ControlPoint>,
    /// Check points.
    pub checkpoints: Vec<ControlPoint>,
    /// Marker observations.
    pub markers: Vec<Marker>,
    /// Priors from the gnss file.
    pub gnss: Vec<GnssPrior>,
    /// Stable areas.
    pub stable_areas: Vec<StableArea>,
    /// Scale bars between marked targets.
    pub scale_bars: Vec<ScaleBarInput>,
    /// Natural points on stable ground (`stable_points.csv`), measured in markers.csv.
    pub stable_points: Vec<csv_inputs::StablePointInput>,
    /// Known focal lengths by camera group (`[[camera]]`).
    pub calibrations: BTreeMap<String, GivenFocal>,
    /// Film cameras by camera group (`[[camera]]` with fiducial marks).
    pub film: BTreeMap<String, crate::film::FilmCamera>,
    /// Fiducial marks measured by hand (`fiducials.csv`).
    pub fiducial_marks: Vec<csv_inputs::FiducialMeasurement>,
    /// `[[camera]] mask` images by camera group.
    pub camera_masks: BTreeMap<String, crate::film::CameraMask>,
    /// Whether the stages draw progress bars (not a setting of the project: the caller's,
    /// `timesift run --quiet`).
    pub progress: crate::progress::Progress,
}

/// A focal length the user gave for a camera group.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GivenFocal {
    /// Focal length, pixels.
    pub focal_px: f64,
    /// Whether the bundle adjustment may refine it.
    pub adjust: bool,
    /// The principal point's offset from the image centre (`cx`, `cy`, pixels) from a film
    /// camera's certificate; the starting value of self-calibration.
    pub principal_point: Option<(f64, f64)>,
    /// k1, k2, k3 from the certificate's distortion curve (`distortion_um`), held.
    pub radial: Option<[f64; 3]>,
}

fn is_image_file(path: &Path) -> bool {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.as_str()))
}

/// `path` relative to `dir`, with `/` separators.
fn relative_name(dir: &Path, path: &Path) -> String {
    let rel = path.strip_prefix(dir).unwrap_or(path);
    rel.components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join("/")
}

/// Normalises a user-written relative image path (`./a//b.jpg` → `a/b.jpg`).
fn normalise_name(name: &str) -> String {
    name.split(['/', '\\'])
        .filter(|c| !c.is_empty() && *c != ".")
        .collect::<Vec<_>>()
        .join("/")
}

/// The `[[camera]]` tables checked: each names a camera group once and gives one positive focal
/// length, in pixels or in millimetres with the pixel size.
fn camera_calibrations(
    cfg_path: &Path,
    config: &ProjectConfig,
    epochs: &[Epoch],
) -> Result<BTreeMap<String, GivenFocal>, ProjectError> {
    let mut out = BTreeMap::new();
    for (i, c) in config.cameras.iter().enumerate() {
        let key = format!("camera[{i}]");
        let error = |field: &str, message: String| {
            ProjectError::config(cfg_path, format!("{key}.{field}"), message)
        };
        if !epochs.iter().any(|e| e.camera_group == c.name) {
            let groups: std::collections::BTreeSet<&str> =
                epochs.iter().map(|e| e.camera_group.as_str()).collect();
            return Err(error(
                "name",
                format!(
                    "\"{}\" is not a camera group of this project (groups: {})",
                    c.name,
                    groups.into_iter().collect::<Vec<_>>().join(", ")
                ),
            ));
        }
        let positive = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(error(field, format!("expected a positive length, got {v}")))
            }
        };
        let focal_px = match (c.focal_px, c.focal_mm, c.pixel_mm) {
            (Some(px), None, None) => positive("focal_px", px)?,
            (None, Some(mm), Some(pixel)) => positive(
                "focal_mm",
                positive("focal_mm", mm)? / positive("pixel_mm", pixel)?,
            )?,
            (Some(_), None, Some(_)) => {
                return Err(error(
                    "pixel_mm",
                    "only with focal_mm (focal_px is already in pixels)".into(),
                ));
            }
            (None, Some(_), None) => {
                return Err(error(
                    "pixel_mm",
                    "missing: focal_mm needs the pixel size in millimetres".into(),
                ));
            }
            (None, None, _) => {
                return Err(error(
                    "focal_px",
                    "missing: give focal_px, or focal_mm with pixel_mm".into(),
                ));
            }
            (Some(_), _, _) => {
                return Err(error(
                    "focal_mm",
                    "give either focal_px or focal_mm with pixel_mm, not both".into(),
                ));
            }
        };
        let given = GivenFocal {
            focal_px,
            adjust: c.adjust_focal,
            principal_point: None,
            radial: crate::film::certificate_radial(c)
                .map_err(|message| error("distortion_um", message))?,
        };
        if out.insert(c.name.clone(), given).is_some() {
            return Err(error(
                "name",
                format!("camera group \"{}\" is calibrated twice", c.name),
            ));
        }
    }
    Ok(out)
}

impl Project {
    /// Loads `project.toml` from `dir` and validates it with every input file it names.
    pub fn load(dir: &Path) -> Result<Self, ProjectError> {
        let config_path = dir.join(PROJECT_FILE);
        if !config_path.is_file() {
            return Err(ProjectError::Path {
                path: config_path,
                message: "no project file (run `timesift init` first)".to_string(),
            });
        }
        let config = ProjectConfig::read(&config_path)?;
        Self::from_config(dir, config)
    }

    /// Validates a configuration against the files of `dir`.
    pub fn from_config(dir: &Path, config: ProjectConfig) -> Result<Self, ProjectError> {
        let cfg_path = dir.join(PROJECT_FILE);
        let crs = projected_crs(&cfg_path, &config)?;
        config
            .cluster
            .validate()
            .map_err(|e| ProjectError::config(&cfg_path, "cluster", e))?;
        let (epochs, images) = epochs_and_images(dir, &cfg_path, &config)?;
        let reference_epoch = match &config.align.reference_epoch {
            None => EpochId(0),
            Some(name) => epochs
                .iter()
                .position(|e| &e.name == name)
                .map(EpochId::from)
                .ok_or_else(|| {
                    ProjectError::config(
                        &cfg_path,
                        "align.reference_epoch",
                        format!("\"{name}\" is not an epoch of this project"),
                    )
                })?,
        };
        let mut calibrations = camera_calibrations(&cfg_path, &config, &epochs)?;
        let film = crate::film::film_cameras(dir, &cfg_path, &config)?;
        let camera_masks = crate::film::camera_masks(dir, &cfg_path, &config)?;
        for (group, f) in &film {
            if let (Some(g), Some(pp)) = (calibrations.get_mut(group), f.principal_point) {
                g.principal_point = Some((pp.x, pp.y));
            }
        }
        let files = InputFiles {
            dir,
            cfg_path: &cfg_path,
            inputs: &config.inputs,
        };
        let image_index: HashMap<&str, usize> = images
            .iter()
            .enumerate()
            .map(|(i, im)| (im.name.as_str(), i))
            .collect();
        let points = files.points(&image_index)?;
        let gnss = files.gnss(&image_index)?;
        let fiducial_marks = files.fiducial_marks(
            &image_index,
            &|i| &epochs[images[i].epoch.index()].camera_group,
            &film,
        )?;
        let stable_areas = match files.path("stable", &config.inputs.stable, "stable.csv")? {
            Some(p) => csv_inputs::read_stable_areas(&p)?,
            None => Vec::new(),
        };
        Ok(Project {
            dir: dir.to_path_buf(),
            config,
            crs,
            epochs,
            images,
            reference_epoch,
            gcps: points.gcps,
            checkpoints: points.checkpoints,
            markers: points.markers,
            gnss,
            stable_areas,
            scale_bars: points.scale_bars,
            stable_points: points.stable_points,
            calibrations,
            film,
            fiducial_marks,
            camera_masks,
            progress: crate::progress::Progress::default(),
        })
    }

    /// The paths of the project's work and output files.
    pub fn layout(&self) -> crate::layout::Layout {
        crate::layout::Layout::new(&self.dir)
    }

    /// What epoch `e`'s images are: film scans when its camera group is film.
    pub fn image_kind(&self, e: usize) -> crate::config::ImageKind {
        match self.epoch_film_camera(e) {
            Some(_) => crate::config::ImageKind::FilmScan,
            None => crate::config::ImageKind::Digital,
        }
    }

    /// The film camera of image `i`, when its camera group is film.
    pub fn film_camera(&self, i: usize) -> Option<&crate::film::FilmCamera> {
        self.epoch_film_camera(self.images.get(i)?.epoch.index())
    }

    /// The film camera of epoch `e`'s camera group, when it is film.
    fn epoch_film_camera(&self, e: usize) -> Option<&crate::film::FilmCamera> {
        self.film.get(&self.epochs.get(e)?.camera_group)
    }

    /// Absolute path of an image.
    pub fn image_path(&self, id: ImageId) -> PathBuf {
        self.dir.join(&self.images[id.index()].name)
    }

    /// Camera groups and the epochs using each, in order of first use.
    pub fn camera_groups(&self) -> BTreeMap<String, Vec<EpochId>> {
        let mut groups: BTreeMap<String, Vec<EpochId>> = BTreeMap::new();
        for (i, e) in self.epochs.iter().enumerate() {
            groups
                .entry(e.camera_group.clone())
                .or_default()
                .push(EpochId::from(i));
        }
        groups
    }

    /// The camera-centre prior of every image: from the gnss file when there is one, else from
    /// EXIF GPS projected into the project CRS (when `[gnss] exif` is on and the CRS is projected).
    pub fn camera_priors(&self) -> Result<Vec<Option<CameraPrior>>, ProjectError> {
        let cfg = &self.config.gnss;
        if !self.gnss.is_empty() {
            let by_name: HashMap<&str, &GnssPrior> =
                self.gnss.iter().map(|g| (g.image.as_str(), g)).collect();
            return Ok(self
                .images
                .iter()
                .map(|im| {
                    by_name.get(im.name.as_str()).map(|g| {
                        let (sxy, sz) = g.sigma.unwrap_or((cfg.sxy, cfg.sz));
                        CameraPrior {
                            position: g.position,
                            sxy,
                            sz,
                            source: PriorSource::GnssFile,
                        }
                    })
                })
                .collect());
        }
        if !cfg.exif || self.crs == Crs::Local {
            return Ok(vec![None; self.images.len()]);
        }
        let projector = Projector::new(self.crs)?;
        let mut priors = Vec::with_capacity(self.images.len());
        for i in 0..self.images.len() {
            let info = exif::read_exif(&self.image_path(ImageId::from(i)))?;
            let prior = match info.gps {
                Some(gps) => {
                    let (e, n) = projector
                        .project(gps.latitude, gps.longitude)
                        .map_err(|e| ProjectError::Path {
                            path: self.image_path(ImageId::from(i)),
                            message: format!("EXIF GPS position cannot be projected: {e}"),
                        })?;
                    gps.altitude.map(|h| CameraPrior {
                        position: Vector3::new(e, n, h),
                        sxy: cfg.sxy,
                        sz: cfg.sz,
                        source: PriorSource::Exif,
                    })
                }
                None => None,
            };
            priors.push(prior);
        }
        Ok(priors)
    }
}

/// Expands one image pattern relative to `dir` into sorted relative names.
fn expand_images(
    dir: &Path,
    cfg_path: &Path,
    key: &str,
    pattern: &str,
) -> Result<Vec<String>, ProjectError> {
    let is_glob = pattern.contains(['*', '?', '[']);
    if !is_glob {
        let p = dir.join(pattern);
        if !p.is_file() {
            return Err(ProjectError::config(
                cfg_path,
                key,
                format!("image \"{pattern}\" does not exist"),
            ));
        }
        return Ok(vec![relative_name(dir, &p)]);
    }
    // The directory is literal text, not part of the pattern (it may contain `[`, `*` or `?`).
    let escaped_dir = glob::Pattern::escape(&dir.to_string_lossy());
    let full = Path::new(&escaped_dir).join(pattern);
    let options = glob::MatchOptions {
        case_sensitive: true,
        require_literal_separator: true,
        require_literal_leading_dot: true,
    };
    let paths = glob::glob_with(&full.to_string_lossy(), options)
        .map_err(|e| ProjectError::config(cfg_path, key, format!("bad glob \"{pattern}\": {e}")))?;
    let mut names = Vec::new();
    for entry in paths {
        let path = entry.map_err(|e| ProjectError::config(cfg_path, key, e.to_string()))?;
        if path.is_file() && is_image_file(&path) {
            names.push(relative_name(dir, &path));
        }
    }
    if names.is_empty() {
        return Err(ProjectError::config(
            cfg_path,
            key,
            format!("\"{pattern}\" matches no image (JPEG, PNG or TIFF)"),
        ));
    }
    names.sort();
    Ok(names)
}
/// The world frame of `config`: a projected CRS (metres) that proj4rs can transform, or local.
fn projected_crs(cfg_path: &Path, config: &ProjectConfig) -> Result<Crs, ProjectError> {
    let crs: Crs = config
        .crs
        .parse()
        .map_err(|m: String| ProjectError::config(cfg_path, "crs", m))?;
    if crs.is_geographic() {
        return Err(ProjectError::config(
            cfg_path,
            "crs",
            format!(
                "{crs} is geographic; the world frame must be projected (metres), e.g. a UTM zone"
            ),
        ));
    }
    if let Crs::Epsg(_) = crs {
        Projector::new(crs).map_err(|e| ProjectError::config(cfg_path, "crs", e.to_string()))?;
    }
    if config.epochs.is_empty() {
        return Err(ProjectError::config(
            cfg_path,
            "epoch",
            "no [[epoch]] is defined",
        ));
    }
    // The epochs a tie point is seen in are a fixed-size set.
    let most = timesift_io::ply::EpochSet::CAPACITY;
    if config.epochs.len() > most {
        return Err(ProjectError::config(
            cfg_path,
            "epoch",
            format!(
                "{} epochs are defined; timesift handles at most {most} in one project",
                config.epochs.len()
            ),
        ));
    }
    Ok(crs)
}

/// The epochs of `config` and their images (each in one epoch only, two or more per epoch),
/// image ids in epoch order.
fn epochs_and_images(
    dir: &Path,
    cfg_path: &Path,
    config: &ProjectConfig,
) -> Result<(Vec<Epoch>, Vec<ProjectImage>), ProjectError> {
    let mut epochs = Vec::new();
    let mut images: Vec<ProjectImage> = Vec::new();
    let mut owner: HashMap<String, usize> = HashMap::new();
    for (e, ec) in config.epochs.iter().enumerate() {
        let key = format!("epoch[{e}]");
        check_epoch_name(cfg_path, config, e)?;
        let names = epoch_image_names(dir, cfg_path, &key, ec)?;
        let mut ids = Vec::with_capacity(names.len());
        for name in names {
            if let Some(&other) = owner.get(&name) {
                return Err(ProjectError::config(
                    cfg_path,
                    format!("{key}.images"),
                    format!(
                        "image \"{name}\" is listed in epoch \"{}\" and in epoch \"{}\"",
                        config.epochs[other].name, ec.name
                    ),
                ));
            }
            owner.insert(name.clone(), e);
            ids.push(ImageId::from(images.len()));
            images.push(ProjectImage {
                name,
                epoch: EpochId::from(e),
            });
        }
        epochs.push(Epoch {
            name: ec.name.clone(),
            camera_group: ec.camera.clone().unwrap_or_else(|| ec.name.clone()),
            images: ids,
        });
    }
    Ok((epochs, images))
}

/// Epoch `e`'s name: non-empty, no slashes or control characters, not `.` or `..`, unique.
fn check_epoch_name(cfg_path: &Path, config: &ProjectConfig, e: usize) -> Result<(), ProjectError> {
    let ec = &config.epochs[e];
    let key = format!("epoch[{e}].name");
    if ec.name.trim().is_empty()
        || ec.name.contains(['/', '\\'])
        || ec.name == "."
        || ec.name == ".."
        || ec.name.chars().any(char::is_control)
    {
        return Err(ProjectError::config(
            cfg_path,
            key,
            format!(
                "\"{}\" is not a valid epoch name (non-empty, no slashes)",
                ec.name
            ),
        ));
    }
    if let Some(first) = config.epochs[..e].iter().position(|o| o.name == ec.name) {
        return Err(ProjectError::config(
            cfg_path,
            key,
            format!("epoch \"{}\" is already defined as epoch[{first}]", ec.name),
        ));
    }
    Ok(())
}

/// The images an epoch's patterns name (default `images/<epoch>/*`), sorted, at least two.
fn epoch_image_names(
    dir: &Path,
    cfg_path: &Path,
    key: &str,
    ec: &EpochConfig,
) -> Result<Vec<String>, ProjectError> {
    let default_pattern = format!("images/{}/*", ec.name);
    let patterns = ec
        .images
        .as_ref()
        .map(|s| s.patterns().into_iter().map(str::to_string).collect())
        .unwrap_or_else(|| vec![default_pattern]);
    let mut names = Vec::new();
    for pattern in &patterns {
        names.extend(expand_images(
            dir,
            cfg_path,
            &format!("{key}.images"),
            pattern,
        )?);
    }
    names.sort();
    names.dedup();
    if names.len() < 2 {
        return Err(ProjectError::config(
            cfg_path,
            format!("{key}.images"),
            format!(
                "epoch \"{}\" has {} image(s); at least 2 are needed",
                ec.name,
                names.len()
            ),
        ));
    }
    Ok(names)
}

/// The CSV inputs of a project: `[inputs]` names them, or they sit at their default names.
struct InputFiles<'a> {
    dir: &'a Path,
    cfg_path: &'a Path,
    inputs: &'a InputsConfig,
}

/// Surveyed and measured points: control, check, scale-bar ends, natural stable points, and
/// the markers that measure them.
struct PointInputs {
    gcps: Vec<ControlPoint>,
    checkpoints: Vec<ControlPoint>,
    scale_bars: Vec<ScaleBarInput>,
    stable_points: Vec<csv_inputs::StablePointInput>,
    markers: Vec<Marker>,
}

impl InputFiles<'_> {
    /// The file of input `key`: the one `[inputs]` names (an error when missing), or the
    /// default when it exists, or none.
    fn path(
        &self,
        key: &str,
        explicit: &Option<String>,
        default: &str,
    ) -> Result<Option<PathBuf>, ProjectError> {
        match explicit {
            Some(name) => {
                let p = self.dir.join(name);
                if p.is_file() {
                    Ok(Some(p))
                } else {
                    Err(ProjectError::config(
                        self.cfg_path,
                        format!("inputs.{key}"),
                        format!("file \"{name}\" does not exist"),
                    ))
                }
            }
            None => {
                let p = self.dir.join(default);
                Ok(p.is_file().then_some(p))
            }
        }
    }

    /// The point files and markers, each name known where it is used: markers name images of
    /// an epoch and points of a file, a stable point is no GCP or check point, and a check
    /// point no GCP.
    fn points(&self, image_index: &HashMap<&str, usize>) -> Result<PointInputs, ProjectError> {
        let inputs = self.inputs;
        let gcps = match self.path("gcps", &inputs.gcps, "gcps.csv")? {
            Some(p) => csv_inputs::read_gcps(&p)?,
            None => Vec::new(),
        };
        let checkpoints_path = self.path("checkpoints", &inputs.checkpoints, "checkpoints.csv")?;
        let checkpoints = match &checkpoints_path {
            Some(p) => csv_inputs::read_checkpoints(p)?,
            None => Vec::new(),
        };
        let scale_bars = match self.path("scalebars", &inputs.scalebars, "scalebars.csv")? {
            Some(p) => csv_inputs::read_scale_bars(&p)?,
            None => Vec::new(),
        };
        let stable_points_path =
            self.path("stable_points", &inputs.stable_points, "stable_points.csv")?;
        let stable_points = match &stable_points_path {
            Some(p) => csv_inputs::read_stable_points(p)?,
            None => Vec::new(),
        };
        if let Some(s) = stable_points
            .iter()
            .find(|s| gcps.iter().chain(&checkpoints).any(|g| g.name == s.name))
        {
            return Err(ProjectError::Reference {
                path: stable_points_path.unwrap_or_default(),
                line: s.line,
                message: format!(
                    "point \"{}\" is also a GCP or check point; a natural stable point has no \
                     surveyed coordinates",
                    s.name
                ),
            });
        }
        let mut points = PointInputs {
            gcps,
            checkpoints,
            scale_bars,
            stable_points,
            markers: Vec::new(),
        };
        if let Some(p) = self.path("markers", &inputs.markers, "markers.csv")? {
            points.markers = csv_inputs::read_markers(&p)?;
            check_markers(&p, &mut points, image_index)?;
        }
        if let Some(c) = points
            .checkpoints
            .iter()
            .find(|c| points.gcps.iter().any(|g| g.name == c.name))
        {
            return Err(ProjectError::Reference {
                path: checkpoints_path.unwrap_or_default(),
                line: c.line,
                message: format!(
                    "point \"{}\" is also a GCP; a check point must be independent",
                    c.name
                ),
            });
        }
        Ok(points)
    }

    /// The camera-centre priors, each naming an image of an epoch.
    fn gnss(&self, image_index: &HashMap<&str, usize>) -> Result<Vec<GnssPrior>, ProjectError> {
        let mut gnss = Vec::new();
        if let Some(p) = self.path("gnss", &self.inputs.gnss, "gnss.csv")? {
            gnss = csv_inputs::read_gnss(&p)?;
            for g in &mut gnss {
                g.image = normalise_name(&g.image);
                if !image_index.contains_key(g.image.as_str()) {
                    return Err(ProjectError::Reference {
                        path: p.clone(),
                        line: g.line,
                        message: format!("unknown image \"{}\" (not in any epoch)", g.image),
                    });
                }
            }
        }
        Ok(gnss)
    }

    /// The measured fiducial marks, each naming an image of an epoch and a mark of its film
    /// camera (`group_of` an image's camera group).
    fn fiducial_marks<'g>(
        &self,
        image_index: &HashMap<&str, usize>,
        group_of: &dyn Fn(usize) -> &'g String,
        film: &BTreeMap<String, crate::film::FilmCamera>,
    ) -> Result<Vec<csv_inputs::FiducialMeasurement>, ProjectError> {
        let mut fiducial_marks = Vec::new();
        let Some(p) = self.path("fiducials", &self.inputs.fiducials, "fiducials.csv")? else {
            return Ok(fiducial_marks);
        };
        fiducial_marks = csv_inputs::read_fiducials(&p)?;
        for m in &mut fiducial_marks {
            m.image = normalise_name(&m.image);
            let Some(&i) = image_index.get(m.image.as_str()) else {
                return Err(ProjectError::Reference {
                    path: p.clone(),
                    line: m.line,
                    message: format!("unknown image \"{}\" (not in any epoch)", m.image),
                });
            };
            let group = group_of(i);
            let known = film
                .get(group)
                .is_some_and(|f| f.frame.marks().iter().any(|k| k.name == m.mark));
            if !known {
                return Err(ProjectError::Reference {
                    path: p.clone(),
                    line: m.line,
                    message: format!(
                        "mark \"{}\" is not a fiducial of camera \"{group}\" ([camera.fiducials])",
                        m.mark
                    ),
                });
            }
        }
        Ok(fiducial_marks)
    }
}

/// Every marker of `path` names an image of an epoch (its name normalised) and a point of the
/// GCP, check-point, scale-bar or stable-point file.
fn check_markers(
    path: &Path,
    points: &mut PointInputs,
    image_index: &HashMap<&str, usize>,
) -> Result<(), ProjectError> {
    let PointInputs {
        gcps,
        checkpoints,
        scale_bars,
        stable_points,
        markers,
    } = points;
    for m in markers.iter_mut() {
        m.image = normalise_name(&m.image);
        if !image_index.contains_key(m.image.as_str()) {
            return Err(ProjectError::Reference {
                path: path.to_path_buf(),
                line: m.line,
                message: format!("unknown image \"{}\" (not in any epoch)", m.image),
            });
        }
        let known = gcps
            .iter()
            .chain(checkpoints.iter())
            .any(|g| g.name == m.name)
            || scale_bars.iter().any(|b| b.a == m.name || b.b == m.name)
            || stable_points.iter().any(|s| s.name == m.name);
        if !known {
            return Err(ProjectError::Reference {
                path: path.to_path_buf(),
                line: m.line,
                message: format!(
                    "unknown point \"{}\" (not in the GCP, check-point, scale-bar or \
                     stable-point file)",
                    m.name
                ),
            });
        }
    }
    Ok(())
}
