//! The description of a multi-epoch scene — surfaces per epoch, land cover, cameras, control
//! points, changed regions — and what follows from it: the surface height of any epoch, the
//! renderable [`Scene`] of an epoch, the stable mask, and the true volume of each region.
//!
//! Geometry is described on a 2-D grid frame (g₁, g₂) with a height `h` above it. For ground
//! scenes the scene's local frame is (x, y, z) = (g₁, g₂, h); for a vertical wall it is
//! (g₁, h, g₂): g₁ runs along the wall, g₂ up it, and `h` is the distance out of the wall towards
//! the cameras. World coordinates add `origin` (e.g. a UTM position) to local ones, so rendering
//! and noise work on small numbers while the written project carries realistic coordinates.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::{BrownCamera, Pose};

use crate::SynthError;
use crate::effects::Effects;
use crate::render::{FieldMaterial, Material, Scene, SceneBuilder, Target};
use crate::shapes::{Block, Bump, Ridge};
use crate::terrain::Heightfield;
use timesift_io::wkt::ring_contains;

/// How far the skirt around a scene's grid drops under the grid's interior, metres: below any
/// change a scene makes.
const APRON_DROP: f64 = 500.0;

/// Most natural stable points a scene offers ([`SceneSpec::natural_candidates`]).
pub const NATURAL_POINTS: usize = 8;

/// Up to `count` of `points` spread over the grid: the farthest-point order, starting from the
/// one nearest the grid's centre. Returns their indices.
pub fn spread_out(
    grid: (f64, f64, f64, usize, usize),
    points: &[(f64, f64)],
    count: usize,
) -> Vec<usize> {
    let (x0, y0, cell, nx, ny) = grid;
    let (w, h) = ((nx - 1) as f64 * cell, (ny - 1) as f64 * cell);
    let centre = (x0 + 0.5 * w, y0 + 0.5 * h);
    let mut chosen: Vec<usize> = Vec::new();
    while chosen.len() < count.min(points.len()) {
        let spread = |p: &(f64, f64)| {
            chosen
                .iter()
                .map(|&c| (points[c].0 - p.0).hypot(points[c].1 - p.1))
                .fold(w.max(h) - (p.0 - centre.0).hypot(p.1 - centre.1), f64::min)
        };
        let Some(next) = (0..points.len())
            .filter(|k| !chosen.contains(k))
            .max_by(|&a, &b| spread(&points[a]).total_cmp(&spread(&points[b])))
        else {
            break;
        };
        chosen.push(next);
    }
    chosen
}

/// How the grid frame sits in the local frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame {
    /// (g₁, g₂, h) = (x, y, z): terrain seen from above.
    Ground,
    /// (g₁, g₂, h) = (x, z, y): a vertical wall in the plane y = 0 facing +y.
    Wall,
}

impl Frame {
    /// Local coordinates of a grid position and height.
    pub fn to_local(self, g1: f64, g2: f64, h: f64) -> Vector3<f64> {
        match self {
            Frame::Ground => Vector3::new(g1, g2, h),
            Frame::Wall => Vector3::new(g1, h, g2),
        }
    }

    /// In-surface axes (for painted targets).
    fn axes(self) -> (Vector3<f64>, Vector3<f64>) {
        match self {
            Frame::Ground => (Vector3::x(), Vector3::y()),
            Frame::Wall => (Vector3::x(), Vector3::z()),
        }
    }
}

/// A height change of the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// A smooth bump or pit.
    Bump(Bump),
    /// An embankment.
    Ridge(Ridge),
}

impl Shape {
    /// Height at a grid position.
    pub fn value(&self, x: f64, y: f64) -> f64 {
        match self {
            Shape::Bump(b) => b.value(x, y),
            Shape::Ridge(r) => r.value(x, y),
        }
    }

    /// Exact volume.
    pub fn volume(&self) -> f64 {
        match self {
            Shape::Bump(b) => b.volume(),
            Shape::Ridge(r) => r.volume(),
        }
    }

    /// A polygon containing the footprint grown by `margin`.
    pub fn footprint(&self, margin: f64) -> Vec<[f64; 2]> {
        match self {
            Shape::Bump(b) => b.footprint(margin),
            Shape::Ridge(r) => r.footprint(margin),
        }
    }
}

/// A shape present in some epochs.
#[derive(Debug, Clone, PartialEq)]
pub struct Feature {
    /// The height change.
    pub shape: Shape,
    /// Indices of the epochs where it is present.
    pub epochs: Vec<usize>,
}

/// A block (ground frame only) present in some epochs.
#[derive(Debug, Clone, PartialEq)]
pub struct PlacedBlock {
    /// The box.
    pub block: Block,
    /// Indices of the epochs where it stands.
    pub epochs: Vec<usize>,
    /// Material of roof and walls.
    pub material: usize,
}

/// A named point on the stable surface: a GCP, check point or scale-bar target.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedPoint {
    /// Name.
    pub name: String,
    /// Grid position.
    pub at: (f64, f64),
}

/// A scale bar: two named targets a known distance apart.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleBar {
    /// First end's target name.
    pub a: String,
    /// Second end's target name.
    pub b: String,
}

/// A region whose surface changes between epochs.
#[derive(Debug, Clone, PartialEq)]
pub struct ChangeRegion {
    /// Name.
    pub name: String,
    /// What it is (for people).
    pub description: String,
    /// Grid-frame polygon containing every feature and block of the region.
    pub polygon: Vec<[f64; 2]>,
    /// Indices into [`SceneSpec::features`].
    pub features: Vec<usize>,
    /// Indices into [`SceneSpec::blocks`].
    pub blocks: Vec<usize>,
}

/// One image to render.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageSpec {
    /// `cam_from_local` pose.
    pub pose: Pose,
    /// Camera and scan effects.
    pub effects: Effects,
}

/// How images are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    /// JPEG of a quality 1–100.
    Jpeg(u8),
    /// Lossless PNG.
    Png,
    /// TIFF, as film scans are delivered.
    Tiff,
}

impl ImageFormat {
    /// File extension.
    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Jpeg(_) => "jpg",
            ImageFormat::Png => "png",
            ImageFormat::Tiff => "tif",
        }
    }
}

/// One epoch: its camera, images and light.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochSpec {
    /// Name (a date).
    pub name: String,
    /// The camera (one group per epoch).
    pub camera: BrownCamera,
    /// Images.
    pub images: Vec<ImageSpec>,
    /// Unit vector towards the sun (local frame).
    pub sun: Vector3<f64>,
    /// Ambient fraction of the light.
    pub ambient: f64,
    /// Whether surfaces cast shadows.
    pub shadows: bool,
    /// Supersampling per axis.
    pub supersampling: u32,
    /// Storage format.
    pub format: ImageFormat,
    /// Film and scan, for photographs scanned from film (the images are then scans: the
    /// photograph inside a frame of fiducial marks, each with a scan transform of its own).
    pub film: Option<crate::film::FilmSpec>,
}

/// Consumer GNSS on the camera: an epoch-wide bias and per-image noise, metres (1σ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GnssSpec {
    /// Horizontal bias per epoch.
    pub bias_h: f64,
    /// Vertical bias per epoch.
    pub bias_v: f64,
    /// Horizontal noise per image.
    pub noise_h: f64,
    /// Vertical noise per image.
    pub noise_v: f64,
}

/// Land cover of a grid position in an epoch: an index into [`SceneSpec::materials`].
pub type CoverFn = Arc<dyn Fn(usize, f64, f64) -> usize + Send + Sync>;
/// Base height of the grid frame (stable part of the surface).
pub type BaseFn = Arc<dyn Fn(f64, f64) -> f64 + Send + Sync>;
/// Texture warp of an epoch (maps a local position to where its texture is evaluated).
pub type WarpFn = Arc<dyn Fn(usize, &Vector3<f64>) -> Vector3<f64> + Send + Sync>;

/// A complete multi-epoch scene.
#[derive(Clone)]
pub struct SceneSpec {
    /// Scene name.
    pub name: String,
    /// The project CRS (`"EPSG:…"` or `"local"`).
    pub crs: String,
    /// World position of the local origin.
    pub origin: Vector3<f64>,
    /// Grid frame.
    pub frame: Frame,
    /// The grid of the surface meshes and truth DEMs: origin (node 0, 0), cell, nodes.
    pub grid: (f64, f64, f64, usize, usize),
    /// Stable surface.
    pub base: BaseFn,
    /// Width (metres) of a coarse skirt of the stable surface around the grid, so that views
    /// reaching past the grid see ground rather than sky; it sits 5 cm below the grid's surface
    /// and carries no truth.
    pub apron: f64,
    /// Height changes.
    pub features: Vec<Feature>,
    /// Boxes.
    pub blocks: Vec<PlacedBlock>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Land cover.
    pub cover: CoverFn,
    /// Texture warp, if the ground moves.
    pub warp: Option<WarpFn>,
    /// Epochs in time order.
    pub epochs: Vec<EpochSpec>,
    /// Ground control points.
    pub gcps: Vec<NamedPoint>,
    /// Check points.
    pub checkpoints: Vec<NamedPoint>,
    /// Scale-bar targets (named points) and bars.
    pub scale_targets: Vec<NamedPoint>,
    /// Scale bars between `scale_targets`.
    pub scale_bars: Vec<ScaleBar>,
    /// Painted target radius, metres.
    pub target_radius: f64,
    /// Changed regions.
    pub regions: Vec<ChangeRegion>,
    /// Polygons (grid frame) of everything that is not stable: changed surfaces, changing cover
    /// (vegetation, water), moving objects.
    pub unstable: Vec<Vec<[f64; 2]>>,
    /// Camera GNSS, when the images carry it.
    pub gnss: Option<GnssSpec>,
    /// Standard deviation of marker observations, pixels.
    pub marker_sigma: f64,
    /// GCP survey noise (horizontal, vertical), metres.
    pub survey_sigma: (f64, f64),
    /// Seed of every random draw made when writing (marker, GNSS and survey noise).
    pub seed: u64,
}

impl SceneSpec {
    /// Makes every epoch that is not already on film a set of film scans (`cargo xtask synth
    /// --film`): its camera's photographs inside a frame of eight marks (the patterns in turn),
    /// scanned as TIFF at the pixel size that makes the frame 230 mm wide.
    pub fn scan_every_epoch(&mut self) {
        use crate::film::{FilmSpec, MarkPattern};
        const PATTERNS: [MarkPattern; 4] = [
            MarkPattern::RcType,
            MarkPattern::RmkType,
            MarkPattern::Cross,
            MarkPattern::DotInCircle,
        ];
        for (e, epoch) in self.epochs.iter_mut().enumerate() {
            if epoch.film.is_some() {
                continue;
            }
            let pixel_mm = 230.0 / epoch.camera.width.max(epoch.camera.height) as f64;
            epoch.film = Some(FilmSpec::eight_marks(
                &epoch.camera,
                pixel_mm,
                PATTERNS[e % PATTERNS.len()],
                nalgebra::Vector2::new(0.003 * e as f64, -0.002 * e as f64),
            ));
            epoch.format = ImageFormat::Tiff;
        }
    }
}

impl SceneSpec {
    /// Keeps the first `n` images of every epoch (in flight order), for a smaller block of the
    /// same ground: tests and examples that need a block, not the whole survey.
    pub fn keep_first_images(&mut self, n: usize) {
        for epoch in &mut self.epochs {
            epoch.images.truncate(n);
        }
    }

    /// The grid as a heightfield layout (origin, cell, nodes) filled with the surface of `epoch`
    /// (base plus the features present then; blocks excluded).
    pub fn heightfield(&self, epoch: usize) -> Heightfield {
        let (x0, y0, cell, nx, ny) = self.grid;
        let active: Vec<&Shape> = self
            .features
            .iter()
            .filter(|f| f.epochs.contains(&epoch))
            .map(|f| &f.shape)
            .collect();
        Heightfield::from_fn((x0, y0), cell, nx, ny, |x, y| {
            // Shapes are zero outside their footprints.
            (self.base)(x, y) + active.iter().map(|s| s.value(x, y)).sum::<f64>()
        })
    }

    /// The true surface height of `epoch` at grid position (x, y): the heightfield (as rendered,
    /// piecewise planar between nodes) or the roof of a block standing there.
    pub fn surface(&self, field: &Heightfield, epoch: usize, x: f64, y: f64) -> Option<f64> {
        let ground = field.height_at(x, y)?;
        Some(
            self.blocks
                .iter()
                .filter(|b| b.epochs.contains(&epoch) && b.block.covers(x, y, 0.0))
                .map(|b| b.block.top)
                .fold(ground, f64::max),
        )
    }

    /// Local position of a named point in `epoch` (points are on stable ground, so any epoch
    /// gives the same position).
    pub fn point_local(
        &self,
        field: &Heightfield,
        p: &NamedPoint,
    ) -> Result<Vector3<f64>, SynthError> {
        let h = field.height_at(p.at.0, p.at.1).ok_or_else(|| {
            SynthError::InvalidScene(format!("point {} outside the grid", p.name))
        })?;
        Ok(self.frame.to_local(p.at.0, p.at.1, h))
    }

    /// Every named point with its kind (`"gcp"`, `"checkpoint"`, `"scalebar"`), in that order.
    pub fn named_points(&self) -> impl Iterator<Item = (&'static str, &NamedPoint)> {
        let tag = |kind: &'static str| move |p| (kind, p);
        self.gcps
            .iter()
            .map(tag("gcp"))
            .chain(self.checkpoints.iter().map(tag("checkpoint")))
            .chain(self.scale_targets.iter().map(tag("scalebar")))
    }

    /// Where natural stable points may be (the `manual` method's unpainted spots — a boulder's
    /// corner, a fence post): grid positions on a lattice over the scene, on stable ground with
    /// a margin, away from the painted targets. The writer keeps those the cameras see and
    /// spreads [`NATURAL_POINTS`] of them over the scene ([`spread_out`]).
    pub fn natural_candidates(&self) -> Vec<(f64, f64)> {
        let (x0, y0, cell, nx, ny) = self.grid;
        let (w, h) = ((nx - 1) as f64 * cell, (ny - 1) as f64 * cell);
        let margin = 0.03 * w.max(h);
        let targets: Vec<(f64, f64)> = self.named_points().map(|(_, p)| p.at).collect();
        let stable_around = |x: f64, y: f64| {
            self.is_stable(x, y)
                && (0..8).all(|k| {
                    let a = k as f64 * std::f64::consts::FRAC_PI_4;
                    self.is_stable(x + margin * a.cos(), y + margin * a.sin())
                })
        };
        let lattice = 16;
        (0..lattice * lattice)
            .map(|k| {
                let (i, j) = ((k % lattice) as f64, (k / lattice) as f64);
                let t = |v: f64| 0.04 + 0.92 * v / (lattice - 1) as f64;
                (x0 + w * t(i), y0 + h * t(j))
            })
            .filter(|&(x, y)| stable_around(x, y))
            .filter(|&(x, y)| targets.iter().all(|t| (t.0 - x).hypot(t.1 - y) > margin))
            .collect()
    }

    /// Whether a grid position is stable (outside every unstable polygon).
    pub fn is_stable(&self, x: f64, y: f64) -> bool {
        !self.unstable.iter().any(|p| ring_contains(p, x, y))
    }

    /// The renderable scene of `epoch`.
    pub fn scene(&self, field: &Heightfield, epoch: usize) -> Result<Scene, SynthError> {
        let mut builder = SceneBuilder::new();
        for m in &self.materials {
            builder.material(m.clone());
        }
        let swap_yz = self.frame == Frame::Wall;
        builder.add_field(field.clone(), swap_yz, FieldMaterial::Cover);
        if self.apron > 0.0 {
            // A coarse skirt of the stable surface around the grid, 5 cm below the grid's
            // surface at its edge. Under the grid's interior it drops far down: there it must
            // never show through the grid, neither where the ground was lowered (a scarp, a
            // pit, thinning ice: a skirt at the stable height would hide the change from the
            // cameras while the truth DEM holds it) nor where the coarse skirt cuts above the
            // fine surface between its nodes. Every triangle touching a dropped node lies
            // inside the grid's footprint, so no hole opens beside the grid.
            let (x0, y0, cell, nx, ny) = self.grid;
            let (x1, y1) = (x0 + (nx - 1) as f64 * cell, y0 + (ny - 1) as f64 * cell);
            let coarse = (cell * 8.0).max(self.apron / 40.0);
            let n = |len: f64| ((len + 2.0 * self.apron) / coarse).ceil() as usize + 1;
            let under_grid = |x: f64, y: f64| {
                x - coarse > x0 && x + coarse < x1 && y - coarse > y0 && y + coarse < y1
            };
            builder.add_field(
                Heightfield::from_fn(
                    (x0 - self.apron, y0 - self.apron),
                    coarse,
                    n((nx - 1) as f64 * cell),
                    n((ny - 1) as f64 * cell),
                    |x, y| {
                        let drop = if under_grid(x, y) { APRON_DROP } else { 0.05 };
                        (self.base)(x, y) - drop
                    },
                ),
                swap_yz,
                FieldMaterial::Cover,
            );
        }
        let cover = self.cover.clone();
        let frame = self.frame;
        builder.cover(Arc::new(move |p: &Vector3<f64>| match frame {
            Frame::Ground => cover(epoch, p.x, p.y),
            Frame::Wall => cover(epoch, p.x, p.z),
        }));
        for b in self.blocks.iter().filter(|b| b.epochs.contains(&epoch)) {
            if self.frame != Frame::Ground {
                return Err(SynthError::InvalidScene(
                    "blocks stand on ground scenes only".into(),
                ));
            }
            let (v, t) = b.block.mesh();
            builder.add_mesh(&v, &t, |_| b.material);
        }
        let (u, v) = self.frame.axes();
        for (_, p) in self.named_points() {
            builder.target(Target {
                centre: self.point_local(field, p)?,
                u,
                v,
                radius: self.target_radius,
            });
        }
        if let Some(warp) = &self.warp {
            let warp = warp.clone();
            builder.warp(Arc::new(move |x| warp(epoch, x)));
        }
        let mut scene = builder.build()?;
        scene.sun = self.epochs[epoch].sun;
        scene.ambient = self.epochs[epoch].ambient;
        scene.background = Vector3::new(0.55, 0.62, 0.72);
        Ok(scene)
    }

    /// The true volume of a region between epochs `a` and `b` (b minus a), from the closed forms.
    pub fn true_volume(&self, region: &ChangeRegion, a: usize, b: usize) -> f64 {
        let presence = |epochs: &[usize]| epochs.contains(&b) as i32 - epochs.contains(&a) as i32;
        let features: f64 = region
            .features
            .iter()
            .map(|&k| presence(&self.features[k].epochs) as f64 * self.features[k].shape.volume())
            .sum();
        let blocks: f64 = region
            .blocks
            .iter()
            .map(|&k| presence(&self.blocks[k].epochs) as f64 * self.blocks[k].block.volume())
            .sum();
        features + blocks
    }
}
