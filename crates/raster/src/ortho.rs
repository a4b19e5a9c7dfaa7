//! True orthomosaics: every ortho cell is sampled straight from an original (distorted) image
//! through the camera model at the DEM's height, from views that see the cell without occlusion
//! (a ray walk over the DEM itself, so facades are not mapped twice).
//!
//! Which view paints a cell is a labelling problem on the DEM lattice: each view's data cost
//! prefers a vertical look and the image centre, and neighbouring cells with different views pay
//! for the colour disagreement of the two views on both cells, so seams settle where the views
//! agree (a few synchronous ICM sweeps). Across the seams the views are feathered, and per-view
//! gains fitted on the overlaps (Brown & Lowe's gain compensation) remove exposure steps.
//!
//! The lattice is processed in tiles with a halo wider than the seam sweeps and the feather, so
//! a tile's cells come out as if the whole lattice had been processed at once, memory holds one
//! tile's images at a time (through [`ViewImages`]), and results do not depend on the number
//! of threads.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use nalgebra::{DMatrix, DVector, Vector2, Vector3};
use rayon::prelude::*;
use timesift_core::{Camera, CameraModel, Pose};

use crate::{Lattice, RasterError};

/// Most views considered for one tile: the nearest to it.
const MAX_CANDIDATES: usize = 32;
/// Weight of the pull of every gain towards 1, relative to the view's overlap terms: enough to
/// fix the overall level (the mean gain stays near 1), too little to hold exposures apart.
const GAIN_PRIOR: f64 = 1e-3;
/// Memory for the bands of the mosaic made at once, beyond one per thread.
const BANDS_IN_FLIGHT_BYTES: usize = 128 << 20;
/// Fixed cost of a seam between two cells, so that equal-colour seams still stay short.
const SEAM_BASE_COST: f32 = 0.05;

/// An 8-bit RGB image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `3 × width × height` samples.
    pub data: Vec<u8>,
}

/// Where the mosaic's images come from, one at a time, so that a block of thousands of images is
/// never held in memory (the root reads them from disk, with a small cache).
pub trait ViewImages: Sync {
    /// The image of view `view` (an index into the views given to [`orthomosaic`]).
    fn image(&self, view: usize) -> Result<Arc<RgbImage>, String>;
}

/// One oriented image: camera and pose, never changed.
#[derive(Debug, Clone, PartialEq)]
pub struct OrthoView {
    /// The camera model of the image's group.
    pub camera: Camera,
    /// The frozen orientation.
    pub cam_from_world: Pose,
}

/// Orthomosaic options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrthoOptions {
    /// Ortho cells per DEM cell along each axis.
    pub factor: usize,
    /// Half-width of the feathering across seams, DEM cells. Default 2.
    pub feather: usize,
    /// Seam sweeps (0: every cell takes its best view). Default 3.
    pub seam_sweeps: usize,
    /// Weight of seam costs against the viewing cost. Default 1.
    pub seam_weight: f32,
    /// Per-view gains fitted on the overlaps. Default true.
    pub gain_compensation: bool,
    /// Pixels black in all channels are no-data (scan borders, masks). Default true.
    pub black_is_nodata: bool,
    /// Tile edge, DEM cells. Default 64.
    pub tile: usize,
}

impl Default for OrthoOptions {
    fn default() -> Self {
        OrthoOptions {
            factor: 1,
            feather: 2,
            seam_sweeps: 3,
            seam_weight: 1.0,
            gain_compensation: true,
            black_is_nodata: true,
            tile: 64,
        }
    }
}

/// Seam and coverage figures of a mosaic.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OrthoStats {
    /// Ortho cells painted by at least one image.
    pub painted_cells: usize,
    /// Mean absolute colour difference (0–255, mean of RGB) between neighbouring ortho cells on
    /// either side of a seam (where the DEM cells' views differ).
    pub seam_jump: f64,
    /// The same between neighbouring ortho cells away from seams: the texture's own contrast,
    /// what `seam_jump` is to be compared with.
    pub interior_jump: f64,
    /// DEM cells on a seam.
    pub seam_cells: usize,
}

/// An orthomosaic on the ortho lattice.
#[derive(Debug, Clone, PartialEq)]
pub struct Ortho {
    /// The lattice (the DEM's, subdivided).
    pub lattice: Lattice,
    /// RGBA per cell, row-major; alpha 0 where no image sees the cell.
    pub rgba: Vec<u8>,
    /// Gain per view and channel (1 without compensation).
    pub gains: Vec<[f64; 3]>,
    /// Seam and coverage figures.
    pub stats: OrthoStats,
}

/// Where [`orthomosaic_by_rows`] hands the mosaic: `(first_row, rgba)` with whole rows; an error
/// stops the mosaic.
pub type RowSink<'a> = dyn FnMut(usize, &[u8]) -> Result<(), String> + 'a;

/// One band of tiles of the mosaic, with its figures.
struct Band {
    rgba: Vec<u8>,
    jumps: JumpSums,
    painted: usize,
}

/// What [`orthomosaic_by_rows`] made, its rows having gone to the caller.
#[derive(Debug, Clone, PartialEq)]
pub struct OrthoSummary {
    /// The lattice (the DEM's, subdivided).
    pub lattice: Lattice,
    /// Gain per view and channel (1 without compensation).
    pub gains: Vec<[f64; 3]>,
    /// Seam and coverage figures.
    pub stats: OrthoStats,
}

/// A view with what the mosaic needs of it precomputed.
struct PreparedView<'a> {
    view: &'a OrthoView,
    center: Vector3<f64>,
    /// Largest squared normalised radius of the image's field: points beyond it are outside
    /// the image even where a distortion polynomial folds them back in.
    field_r2: f64,
    /// DEM cells its footprint can touch: (col0, row0, col1, row1), inclusive.
    cells: (usize, usize, usize, usize),
}

/// The DEM and the options, shared by all tiles.
struct Context<'a> {
    lattice: &'a Lattice,
    heights: &'a [f32],
    max_height: f64,
    /// The highest ground per block, for the occlusion march.
    blocks: BlockMax,
    views: Vec<PreparedView<'a>>,
    options: OrthoOptions,
}

/// The highest ground of every block of [`BlockMax::SIZE`]² cells (NaN cells ignored, −∞ for a
/// block without ground): a ray above a block's highest ground cannot be hidden inside it.
struct BlockMax {
    /// Blocks per row.
    columns: usize,
    /// Row-major block maxima.
    heights: Vec<f32>,
}

impl BlockMax {
    /// Cells per block side: a ray crosses a block in about 32 quarter-cell samples, skipped
    /// for one comparison.
    const SIZE: usize = 8;

    fn new(heights: &[f32], width: usize, height: usize) -> BlockMax {
        let columns = width.div_ceil(Self::SIZE);
        let rows = height.div_ceil(Self::SIZE);
        let mut blocks = vec![f32::NEG_INFINITY; columns * rows];
        for (row, line) in heights.chunks_exact(width).enumerate() {
            let block_row = &mut blocks[(row / Self::SIZE) * columns..][..columns];
            for (col, &h) in line.iter().enumerate() {
                let b = &mut block_row[col / Self::SIZE];
                *b = b.max(h);
            }
        }
        BlockMax {
            columns,
            heights: blocks,
        }
    }

    /// The highest ground of the block of cell (col, row).
    fn at(&self, col: usize, row: usize) -> f32 {
        self.heights[(row / Self::SIZE) * self.columns + col / Self::SIZE]
    }

    /// Where the ray `p + s / horizontal · d` (s: horizontal distance from `p`) leaves the block
    /// of cell (col, row).
    fn exit(
        &self,
        l: &Lattice,
        col: usize,
        row: usize,
        p: &Vector3<f64>,
        d: &Vector3<f64>,
        horizontal: f64,
    ) -> f64 {
        let c0 = (col / Self::SIZE) * Self::SIZE;
        let r0 = (row / Self::SIZE) * Self::SIZE;
        let c1 = (c0 + Self::SIZE).min(l.width());
        let r1 = (r0 + Self::SIZE).min(l.height());
        let (west, east) = (
            l.west() + c0 as f64 * l.cell_width(),
            l.west() + c1 as f64 * l.cell_width(),
        );
        let (north, south) = (
            l.north() - r0 as f64 * l.cell_height(),
            l.north() - r1 as f64 * l.cell_height(),
        );
        let along = |from: f64, towards: f64, low: f64, high: f64| {
            if towards > 0.0 {
                (high - from) * horizontal / towards
            } else if towards < 0.0 {
                (low - from) * horizontal / towards
            } else {
                f64::INFINITY
            }
        };
        along(p.x, d.x, west, east).min(along(p.y, d.y, south, north))
    }
}

/// Mosaics `views` onto the DEM (`heights` on `lattice`, NaN = none), in memory; see
/// [`orthomosaic_by_rows`] for mosaics larger than memory.
pub fn orthomosaic(
    heights: &[f32],
    lattice: &Lattice,
    views: &[OrthoView],
    images: &dyn ViewImages,
    options: &OrthoOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Ortho, RasterError> {
    let mut rgba = Vec::new();
    let summary = orthomosaic_by_rows(
        heights,
        lattice,
        views,
        images,
        options,
        progress,
        &mut |_, rows| {
            rgba.extend_from_slice(rows);
            Ok(())
        },
    )?;
    Ok(Ortho {
        lattice: summary.lattice,
        rgba,
        gains: summary.gains,
        stats: summary.stats,
    })
}

/// Mosaics `views` onto the DEM (`heights` on `lattice`, NaN = none) and hands the mosaic to
/// `rows` a band at a time, top to bottom: `rows(first_row, rgba)` with whole rows of the
/// ortho lattice (RGBA, alpha 0 where no image sees the cell), so that memory holds a few
/// bands of tiles, never the mosaic (an error `rows` returns stops the work). `progress` is
/// told (tiles done, tiles to do) as the work goes (the gain fit visits every tile once too).
/// The rows do not depend on the number of threads. The same mosaic made in parts
/// ([`OrthoMosaic`]) has the same rows and figures, bit for bit.
pub fn orthomosaic_by_rows(
    heights: &[f32],
    lattice: &Lattice,
    views: &[OrthoView],
    images: &dyn ViewImages,
    options: &OrthoOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
    rows: &mut RowSink<'_>,
) -> Result<OrthoSummary, RasterError> {
    let mosaic = OrthoMosaic::new(heights, lattice, views, options)?;
    let tiles = mosaic.tiles.len();
    let total = tiles * if options.gain_compensation { 2 } else { 1 };
    let gains = mosaic.gains(images, &|done, _| progress(done, total))?;
    let offset = total - tiles;
    let figures = mosaic.make_rows(
        0..mosaic.tile_rows(),
        images,
        &gains,
        &|done, _| progress(offset + done, total),
        rows,
    )?;
    Ok(OrthoSummary {
        lattice: mosaic.ortho_lattice,
        gains,
        stats: ortho_stats(&figures),
    })
}

/// What one row of tiles of a mosaic adds to its figures ([`OrthoStats`]): kept per row, so
/// that a mosaic made in parts sums them in the same order as one made whole.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TileRowFigures {
    /// Ortho cells painted.
    pub painted_cells: usize,
    /// Sum of the colour jumps across seams (see [`OrthoStats::seam_jump`]).
    pub seam_sum: f64,
    /// Neighbouring pairs of ortho cells across seams.
    pub seam_pairs: usize,
    /// Sum of the colour jumps away from seams.
    pub interior_sum: f64,
    /// Neighbouring pairs away from seams.
    pub interior_pairs: usize,
}

/// The figures of a mosaic from its tile rows' figures, top to bottom.
pub fn ortho_stats(figures: &[TileRowFigures]) -> OrthoStats {
    let mut sums = JumpSums::default();
    let mut stats = OrthoStats::default();
    for f in figures {
        stats.painted_cells += f.painted_cells;
        sums.add(&JumpSums {
            seam: f.seam_sum,
            seam_n: f.seam_pairs,
            interior: f.interior_sum,
            interior_n: f.interior_pairs,
        });
    }
    stats.seam_cells = sums.seam_n;
    stats.seam_jump = sums.seam / sums.seam_n.max(1) as f64;
    stats.interior_jump = sums.interior / sums.interior_n.max(1) as f64;
    stats
}

/// A mosaic to be made, perhaps in parts (a cluster's tasks): the DEM and the views prepared.
/// [`Self::gains`] once, then [`Self::make_rows`] over disjoint ranges of tile rows, in any
/// order and in any process, give the rows and figures (through [`ortho_stats`], in order)
/// that [`orthomosaic_by_rows`] gives: each tile is made from the DEM, the views and the
/// gains alone.
pub struct OrthoMosaic<'a> {
    ctx: Context<'a>,
    tiles: Vec<(usize, usize, usize, usize)>,
    ortho_lattice: Lattice,
}

impl<'a> OrthoMosaic<'a> {
    /// The mosaic of `views` onto the DEM (`heights` on `lattice`, NaN = none).
    pub fn new(
        heights: &'a [f32],
        lattice: &'a Lattice,
        views: &'a [OrthoView],
        options: &OrthoOptions,
    ) -> Result<OrthoMosaic<'a>, RasterError> {
        validate(heights, lattice, views, options)?;
        let finite = heights.iter().filter(|h| h.is_finite());
        let (min_height, max_height) = finite
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), h| {
                (lo.min(*h as f64), hi.max(*h as f64))
            });
        if !min_height.is_finite() {
            return Err(RasterError::InvalidInput(
                "the DEM has no height: nothing to project the images onto".into(),
            ));
        }
        let prepared = views
            .iter()
            .map(|v| prepare_view(v, lattice, min_height, max_height))
            .collect();
        let ctx = Context {
            lattice,
            heights,
            max_height,
            blocks: BlockMax::new(heights, lattice.width(), lattice.height()),
            views: prepared,
            options: *options,
        };
        Ok(OrthoMosaic {
            ctx,
            tiles: tiles_of(lattice, options.tile),
            ortho_lattice: lattice.subdivided(options.factor)?,
        })
    }

    /// The ortho lattice (the DEM's, subdivided).
    pub fn lattice(&self) -> &Lattice {
        &self.ortho_lattice
    }

    /// Rows of tiles: the units the mosaic can be made in.
    pub fn tile_rows(&self) -> usize {
        self.ctx.lattice.height().div_ceil(self.ctx.options.tile)
    }

    /// The rows of the ortho lattice that `tile_rows` make.
    pub fn ortho_rows(&self, tile_rows: std::ops::Range<usize>) -> std::ops::Range<usize> {
        let band = self.ctx.options.tile * self.ctx.options.factor;
        let height = self.ortho_lattice.height();
        (tile_rows.start * band).min(height)..(tile_rows.end * band).min(height)
    }

    /// The gain per view and channel (1 everywhere without gain compensation): a fit over the
    /// overlaps of every tile. `progress` is told (tiles done, tiles).
    pub fn gains(
        &self,
        images: &dyn ViewImages,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Vec<[f64; 3]>, RasterError> {
        if !self.ctx.options.gain_compensation {
            return Ok(vec![[1.0; 3]; self.ctx.views.len()]);
        }
        let total = self.tiles.len();
        let done = AtomicUsize::new(0);
        let tick = || progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        fit_gains(&self.ctx, &self.tiles, images, &tick)
    }

    /// The rows of `tile_rows` with `gains` (one per view, [`Self::gains`]), handed to `rows`
    /// top to bottom as [`orthomosaic_by_rows`] hands them (first row counted from the top of
    /// the whole mosaic); each tile row's figures. `progress` is told (tiles done, tiles).
    pub fn make_rows(
        &self,
        tile_rows: std::ops::Range<usize>,
        images: &dyn ViewImages,
        gains: &[[f64; 3]],
        progress: &(dyn Fn(usize, usize) + Sync),
        rows: &mut RowSink<'_>,
    ) -> Result<Vec<TileRowFigures>, RasterError> {
        let ctx = &self.ctx;
        if gains.len() != ctx.views.len() {
            return Err(RasterError::InvalidInput(format!(
                "{} gains for {} views",
                gains.len(),
                ctx.views.len()
            )));
        }
        let tiles_down = self.tile_rows();
        let tile_rows = tile_rows.start.min(tiles_down)..tile_rows.end.min(tiles_down);
        let f = ctx.options.factor;
        let (ow, oh) = (self.ortho_lattice.width(), self.ortho_lattice.height());
        let tiles_across = ctx.lattice.width().div_ceil(ctx.options.tile);
        let band_rows = ctx.options.tile * f;
        let total = tile_rows.len() * tiles_across;
        let done = AtomicUsize::new(0);
        let tick = || progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        // Bands of tiles are made a batch at a time, in parallel, and handed over in order: two
        // bands per thread keep the threads busy, one per thread where bands are large (a wide
        // mosaic), so that memory grows with the mosaic's width, never with its area.
        let threads = rayon::current_num_threads().max(1);
        let band_bytes = (band_rows * ow * 4).max(1);
        let batch = (BANDS_IN_FLIGHT_BYTES / band_bytes).clamp(threads, 2 * threads);
        let mut figures = Vec::with_capacity(tile_rows.len());
        for first in tile_rows.clone().step_by(batch) {
            let bands: Vec<Result<Band, RasterError>> = (first..(first + batch).min(tile_rows.end))
                .into_par_iter()
                .map(|tile_row| {
                    let row0 = tile_row * band_rows;
                    let mut out = vec![0u8; band_rows.min(oh - row0) * ow * 4];
                    let mut jumps = JumpSums::default();
                    let mut painted = 0;
                    for tile_col in 0..tiles_across {
                        let core = self.tiles[tile_row * tiles_across + tile_col];
                        let tile = TileData::compute(ctx, core, images, gains)?;
                        painted += tile.paint(ctx, &mut out, row0, &mut jumps);
                        tick();
                    }
                    Ok(Band {
                        rgba: out,
                        jumps,
                        painted,
                    })
                })
                .collect();
            for (tile_row, band) in (first..).zip(bands) {
                let band = band?;
                figures.push(TileRowFigures {
                    painted_cells: band.painted,
                    seam_sum: band.jumps.seam,
                    seam_pairs: band.jumps.seam_n,
                    interior_sum: band.jumps.interior,
                    interior_pairs: band.jumps.interior_n,
                });
                rows(tile_row * band_rows, &band.rgba).map_err(RasterError::Output)?;
            }
        }
        Ok(figures)
    }
}

fn validate(
    heights: &[f32],
    lattice: &Lattice,
    views: &[OrthoView],
    options: &OrthoOptions,
) -> Result<(), RasterError> {
    if heights.len() != lattice.len() {
        return Err(RasterError::InvalidInput(format!(
            "{} heights for a lattice of {} cells",
            heights.len(),
            lattice.len()
        )));
    }
    if views.is_empty() {
        return Err(RasterError::InvalidInput(
            "no oriented image to mosaic".into(),
        ));
    }
    if options.factor == 0 || options.tile < 8 || !(options.seam_weight >= 0.0) {
        return Err(RasterError::InvalidOption(format!(
            "ortho factor {} (≥ 1), tile {} (≥ 8 cells) and seam weight {} (≥ 0)",
            options.factor, options.tile, options.seam_weight
        )));
    }
    Ok(())
}

fn prepare_view<'a>(
    view: &'a OrthoView,
    lattice: &Lattice,
    min_height: f64,
    max_height: f64,
) -> PreparedView<'a> {
    let cam = &view.camera;
    let (w, h) = (cam.width() as f64, cam.height() as f64);
    let center = view.cam_from_world.center();
    let world_from_cam = view.cam_from_world.inverse();
    let n = 16;
    let mut field_r2: f64 = 0.0;
    let (mut x0, mut y0, mut x1, mut y1) = (
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    );
    let mut whole = false;
    for k in 0..4 * n {
        let t = (k % n) as f64 / n as f64;
        let (u, v) = match k / n {
            0 => (t * w, 0.0),
            1 => (w, t * h),
            2 => (w - t * w, h),
            _ => (0.0, h - t * h),
        };
        let Ok(ray) = cam.unproject(&Vector2::new(u, v)) else {
            whole = true;
            continue;
        };
        field_r2 = field_r2.max(ray.x * ray.x + ray.y * ray.y);
        let d = world_from_cam.rotation * ray;
        // Where the ray meets the lowest and highest ground; a ray that does not go down far
        // enough to meet both sees to the horizon, so the footprint is the whole lattice.
        for z in [min_height, max_height] {
            let s = (z - center.z) / d.z;
            if !(s > 0.0 && s.is_finite()) {
                whole = true;
                continue;
            }
            let p = center + d * s;
            x0 = x0.min(p.x);
            y0 = y0.min(p.y);
            x1 = x1.max(p.x);
            y1 = y1.max(p.y);
        }
    }
    let last = (lattice.width() - 1, lattice.height() - 1);
    let cells = if whole || !x0.is_finite() {
        (0, 0, last.0, last.1)
    } else {
        let (c0, r0) = lattice.continuous_index(x0, y1);
        let (c1, r1) = lattice.continuous_index(x1, y0);
        let clamp = |v: f64, hi: usize| v.clamp(0.0, hi as f64) as usize;
        if c1 < -1.0 || r1 < -1.0 || c0 > last.0 as f64 + 1.0 || r0 > last.1 as f64 + 1.0 {
            // Sees nothing of the lattice: an empty range.
            (1, 1, 0, 0)
        } else {
            (
                clamp(c0.floor() - 1.0, last.0),
                clamp(r0.floor() - 1.0, last.1),
                clamp(c1.ceil() + 1.0, last.0),
                clamp(r1.ceil() + 1.0, last.1),
            )
        }
    };
    PreparedView {
        view,
        center,
        field_r2: field_r2 * 1.02,
        cells,
    }
}

/// Core rectangles (col0, row0, col1, row1 exclusive) of the tiles, row-major.
fn tiles_of(lattice: &Lattice, tile: usize) -> Vec<(usize, usize, usize, usize)> {
    let mut out = Vec::new();
    for r in (0..lattice.height()).step_by(tile) {
        for c in (0..lattice.width()).step_by(tile) {
            out.push((
                c,
                r,
                (c + tile).min(lattice.width()),
                (r + tile).min(lattice.height()),
            ));
        }
    }
    out
}

impl Context<'_> {
    /// Height at a world position: bilinear between cell centres, the nearest cell's where a
    /// neighbour has none.
    fn height_at(&self, x: f64, y: f64) -> f64 {
        let l = self.lattice;
        let (ci, ri) = l.continuous_index(x, y);
        let c0 = ci.floor().clamp(0.0, (l.width() - 1) as f64) as usize;
        let r0 = ri.floor().clamp(0.0, (l.height() - 1) as f64) as usize;
        let c1 = (c0 + 1).min(l.width() - 1);
        let r1 = (r0 + 1).min(l.height() - 1);
        let (fx, fy) = (
            (ci - c0 as f64).clamp(0.0, 1.0),
            (ri - r0 as f64).clamp(0.0, 1.0),
        );
        let h = |c: usize, r: usize| self.heights[r * l.width() + c] as f64;
        let (a, b, c, d) = (h(c0, r0), h(c1, r0), h(c0, r1), h(c1, r1));
        if a.is_finite() && b.is_finite() && c.is_finite() && d.is_finite() {
            (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
        } else {
            let nc = ci.round().clamp(0.0, (l.width() - 1) as f64) as usize;
            let nr = ri.round().clamp(0.0, (l.height() - 1) as f64) as usize;
            h(nc, nr)
        }
    }

    /// Whether the DEM hides `p` from the camera centre `c`. The DEM is taken as it is stored,
    /// a constant height per cell, so an edge (a roof, a cliff) stands exactly on the cell
    /// boundary; the ray is sampled every quarter cell from one cell away (the point's own
    /// cell cannot hide it) until it rises above the highest ground. A cell hides the point
    /// when it stands above the ray by more than a tenth of a cell: the DEM's own roughness.
    ///
    /// Where the ray passes above the highest ground of a block of cells ([`BlockMax`]), the
    /// samples left in that block are skipped: none of them can be hidden (the ray only rises
    /// towards the camera), so the answer is the one of the plain march, sample for sample.
    fn occluded(&self, p: &Vector3<f64>, c: &Vector3<f64>) -> bool {
        let l = self.lattice;
        let d = c - p;
        let horizontal = (d.x * d.x + d.y * d.y).sqrt();
        if horizontal < 1e-9 {
            return false;
        }
        let cell = l.cell_width().min(l.cell_height());
        let tolerance = 0.1 * cell;
        let step = 0.25 * cell;
        let rising = d.z >= 0.0;
        let mut s = cell;
        while s < horizontal {
            let t = s / horizontal;
            let z = p.z + t * d.z;
            if z > self.max_height + tolerance {
                return false;
            }
            let (x, y) = (p.x + t * d.x, p.y + t * d.y);
            let Some((col, row)) = l.cell_of(x, y) else {
                return false;
            };
            let ground = self.heights[row * l.width() + col] as f64;
            if ground > z + tolerance {
                return true;
            }
            s += step;
            if rising && z > self.blocks.at(col, row) as f64 + tolerance {
                // Every later sample inside the block lies higher still: skip to the first
                // one that may be outside it (the bound is pulled in by a millionth of a cell,
                // so a sample on the border is looked at rather than skipped).
                let exit = self.blocks.exit(l, col, row, p, &d, horizontal) - 1e-6 * cell;
                while s < exit {
                    s += step;
                }
            }
        }
        false
    }

    /// The view's viewing cost of a ground point (lower is better) and its pixel, or `None` when
    /// the point is outside the image or hidden.
    fn look(&self, v: &PreparedView<'_>, p: &Vector3<f64>) -> Option<(f32, Vector2<f64>)> {
        let cam = &v.view.camera;
        let pc = v.view.cam_from_world.transform_point(p);
        if !(pc.z > 0.0) || (pc.x * pc.x + pc.y * pc.y) > v.field_r2 * pc.z * pc.z {
            return None;
        }
        let px = cam.project(&pc).ok()?;
        let (w, h) = (cam.width() as f64, cam.height() as f64);
        if !(px.x >= 0.5 && px.y >= 0.5 && px.x <= w - 0.5 && px.y <= h - 0.5) {
            return None;
        }
        if self.occluded(p, &v.center) {
            return None;
        }
        let ray = v.center - p;
        let cos_vertical = ray.z / ray.norm();
        let dx = (px.x - 0.5 * w) / (0.5 * w);
        let dy = (px.y - 0.5 * h) / (0.5 * h);
        let radial = 0.5 * (dx * dx + dy * dy);
        Some(((1.0 - cos_vertical + 0.5 * radial) as f32, px))
    }

    /// Views whose footprint touches the rectangle, nearest first, at most [`MAX_CANDIDATES`].
    fn candidates(&self, rect: (usize, usize, usize, usize)) -> Vec<usize> {
        let (c0, r0, c1, r1) = rect;
        let (cx, cy) = self.lattice.cell_center((c0 + c1) / 2, (r0 + r1) / 2);
        let mut found: Vec<(f64, usize)> = self
            .views
            .iter()
            .enumerate()
            .filter(|(_, v)| {
                let (a0, b0, a1, b1) = v.cells;
                a0 <= a1 && a0 < c1 && a1 >= c0 && b0 < r1 && b1 >= r0
            })
            .map(|(i, v)| ((v.center.x - cx).powi(2) + (v.center.y - cy).powi(2), i))
            .collect();
        found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        found.truncate(MAX_CANDIDATES);
        found.into_iter().map(|(_, i)| i).collect()
    }
}

/// Bilinear RGB at a pixel position (docs/design.md pixel convention); `None` where a black pixel
/// marks no-data.
fn sample(image: &RgbImage, px: &Vector2<f64>, black_is_nodata: bool) -> Option<[f32; 3]> {
    if image.width == 0 || image.height == 0 || image.data.len() < 3 * image.width * image.height {
        return None;
    }
    let (x, y) = (px.x - 0.5, px.y - 0.5);
    let x0 = (x.floor().max(0.0) as usize).min(image.width.saturating_sub(2));
    let y0 = (y.floor().max(0.0) as usize).min(image.height.saturating_sub(2));
    let (fx, fy) = (
        (x - x0 as f64).clamp(0.0, 1.0),
        (y - y0 as f64).clamp(0.0, 1.0),
    );
    let at = |c: usize, r: usize| {
        let i = 3 * (r.min(image.height - 1) * image.width + c.min(image.width - 1));
        [image.data[i], image.data[i + 1], image.data[i + 2]]
    };
    let q = [
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    ];
    if black_is_nodata && q.contains(&[0, 0, 0]) {
        return None;
    }
    let w = [
        (1.0 - fx) * (1.0 - fy),
        fx * (1.0 - fy),
        (1.0 - fx) * fy,
        fx * fy,
    ];
    let mut out = [0.0f32; 3];
    for (p, wk) in q.iter().zip(w) {
        for b in 0..3 {
            out[b] += (wk * p[b] as f64) as f32;
        }
    }
    Some(out)
}

/// Per-pair overlap sums of the gain fit: samples and summed intensities of each view.
#[derive(Debug, Clone, Copy, Default)]
struct PairSums {
    n: f64,
    a: [f64; 3],
    b: [f64; 3],
}

/// Overlap sums per pair of views (lower index first).
type Overlaps = BTreeMap<(usize, usize), PairSums>;

/// Per-view gains from the overlaps, sampled on a sparse subset of the DEM cells.
fn fit_gains(
    ctx: &Context<'_>,
    tiles: &[(usize, usize, usize, usize)],
    images: &dyn ViewImages,
    tick: &(dyn Fn() + Sync),
) -> Result<Vec<[f64; 3]>, RasterError> {
    let l = ctx.lattice;
    // About 40 000 samples over the lattice.
    let step = ((l.len() as f64 / 40_000.0).sqrt().floor() as usize).max(1);
    let per_tile: Vec<Result<Overlaps, RasterError>> = tiles
        .par_iter()
        .map(|&rect| {
            let mut pairs = BTreeMap::new();
            let cands = ctx.candidates(rect);
            tick();
            if cands.is_empty() {
                return Ok(pairs);
            }
            let imgs = load(&cands, images)?;
            let mut seen: Vec<(usize, [f32; 3])> = Vec::with_capacity(cands.len());
            let (c0, r0, c1, r1) = rect;
            for row in (r0.div_ceil(step) * step..r1).step_by(step) {
                for col in (c0.div_ceil(step) * step..c1).step_by(step) {
                    let h = ctx.heights[row * l.width() + col] as f64;
                    if !h.is_finite() {
                        continue;
                    }
                    let (x, y) = l.cell_center(col, row);
                    let p = Vector3::new(x, y, h);
                    seen.clear();
                    for (k, &v) in cands.iter().enumerate() {
                        if let Some((_, px)) = ctx.look(&ctx.views[v], &p)
                            && let Some(rgb) = sample(&imgs[k], &px, ctx.options.black_is_nodata)
                        {
                            seen.push((v, rgb));
                        }
                    }
                    for i in 0..seen.len() {
                        for j in i + 1..seen.len() {
                            let ((a, ca), (b, cb)) = if seen[i].0 < seen[j].0 {
                                (seen[i], seen[j])
                            } else {
                                (seen[j], seen[i])
                            };
                            let s: &mut PairSums = pairs.entry((a, b)).or_default();
                            s.n += 1.0;
                            for ch in 0..3 {
                                s.a[ch] += ca[ch] as f64;
                                s.b[ch] += cb[ch] as f64;
                            }
                        }
                    }
                }
            }
            Ok(pairs)
        })
        .collect();
    let mut pairs = Overlaps::new();
    for t in per_tile {
        for (k, s) in t? {
            let e = pairs.entry(k).or_default();
            e.n += s.n;
            for ch in 0..3 {
                e.a[ch] += s.a[ch];
                e.b[ch] += s.b[ch];
            }
        }
    }
    Ok(solve_gains(ctx.views.len(), &pairs))
}

/// Minimises Σ N_ab (g_a Ī_ab − g_b Ī_ba)² per channel (Brown & Lowe's gain compensation) with a
/// weak pull of every gain towards 1; views without overlaps keep gain 1.
fn solve_gains(n_views: usize, pairs: &Overlaps) -> Vec<[f64; 3]> {
    let mut gains = vec![[1.0; 3]; n_views];
    for ch in 0..3 {
        let mut a = DMatrix::<f64>::zeros(n_views, n_views);
        for (&(i, j), s) in pairs {
            let (ia, ib) = (s.a[ch] / s.n, s.b[ch] / s.n);
            a[(i, i)] += s.n * ia * ia;
            a[(j, j)] += s.n * ib * ib;
            a[(i, j)] -= s.n * ia * ib;
            a[(j, i)] -= s.n * ia * ib;
        }
        let mut b = DVector::<f64>::zeros(n_views);
        for i in 0..n_views {
            let prior = GAIN_PRIOR * a[(i, i)] + 1e-9;
            a[(i, i)] += prior;
            b[i] += prior;
        }
        if let Some(chol) = a.cholesky() {
            let g = chol.solve(&b);
            for i in 0..n_views {
                if g[i].is_finite() && g[i] > 0.0 {
                    gains[i][ch] = g[i];
                }
            }
        }
    }
    gains
}

fn load(cands: &[usize], images: &dyn ViewImages) -> Result<Vec<Arc<RgbImage>>, RasterError> {
    cands
        .iter()
        .map(|&v| {
            images
                .image(v)
                .map_err(|e| RasterError::InvalidInput(format!("image of view {v}: {e}")))
        })
        .collect()
}

/// Running sums of the colour differences between neighbouring ortho cells.
#[derive(Debug, Default)]
struct JumpSums {
    seam: f64,
    seam_n: usize,
    interior: f64,
    interior_n: usize,
}

impl JumpSums {
    fn add(&mut self, other: &JumpSums) {
        self.seam += other.seam;
        self.seam_n += other.seam_n;
        self.interior += other.interior;
        self.interior_n += other.interior_n;
    }
}

/// One tile with its halo: visibility, colours and labels of every DEM cell.
struct TileData {
    /// The tile with its halo: (col0, row0, col1, row1 exclusive).
    ext: (usize, usize, usize, usize),
    core: (usize, usize, usize, usize),
    cands: Vec<usize>,
    images: Vec<Arc<RgbImage>>,
    /// Per (cell, candidate): viewing cost, ∞ where not seen.
    cost: Vec<f32>,
    /// Per (cell, candidate): colour at the cell centre, gains applied.
    colour: Vec<[f32; 3]>,
    /// Per cell: the painting candidate, `u8::MAX` for none.
    label: Vec<u8>,
    gains: Vec<[f64; 3]>,
}

impl TileData {
    fn compute(
        ctx: &Context<'_>,
        core: (usize, usize, usize, usize),
        images: &dyn ViewImages,
        gains: &[[f64; 3]],
    ) -> Result<TileData, RasterError> {
        let l = ctx.lattice;
        let halo = ctx.options.seam_sweeps + ctx.options.feather + 2;
        let ext = (
            core.0.saturating_sub(halo),
            core.1.saturating_sub(halo),
            (core.2 + halo).min(l.width()),
            (core.3 + halo).min(l.height()),
        );
        let cands = ctx.candidates(ext);
        let loaded = load(&cands, images)?;
        let k = cands.len();
        let (ew, eh) = (ext.2 - ext.0, ext.3 - ext.1);
        let mut cost = vec![f32::INFINITY; ew * eh * k];
        let mut colour = vec![[0.0f32; 3]; ew * eh * k];
        let tile_gains: Vec<[f64; 3]> = cands.iter().map(|&v| gains[v]).collect();
        for r in 0..eh {
            for c in 0..ew {
                let (col, row) = (ext.0 + c, ext.1 + r);
                let h = ctx.heights[row * l.width() + col] as f64;
                if !h.is_finite() {
                    continue;
                }
                let (x, y) = l.cell_center(col, row);
                let p = Vector3::new(x, y, h);
                for (j, &v) in cands.iter().enumerate() {
                    if let Some((score, px)) = ctx.look(&ctx.views[v], &p)
                        && let Some(rgb) = sample(&loaded[j], &px, ctx.options.black_is_nodata)
                    {
                        let i = (r * ew + c) * k + j;
                        cost[i] = score;
                        colour[i] = apply_gain(rgb, &tile_gains[j]);
                    }
                }
            }
        }
        let mut tile = TileData {
            ext,
            core,
            cands,
            images: loaded,
            cost,
            colour,
            label: vec![u8::MAX; ew * eh],
            gains: tile_gains,
        };
        tile.label_cells(ctx);
        Ok(tile)
    }

    fn width(&self) -> usize {
        self.ext.2 - self.ext.0
    }

    /// Best view per cell, then synchronous sweeps trading viewing cost for seam cost.
    fn label_cells(&mut self, ctx: &Context<'_>) {
        let k = self.cands.len();
        let (ew, eh) = (self.width(), self.ext.3 - self.ext.1);
        for cell in 0..ew * eh {
            let costs = &self.cost[cell * k..(cell + 1) * k];
            if let Some((j, _)) = costs
                .iter()
                .enumerate()
                .filter(|(_, c)| c.is_finite())
                .min_by(|a, b| a.1.total_cmp(b.1).then(a.0.cmp(&b.0)))
            {
                self.label[cell] = j as u8;
            }
        }
        let lambda = ctx.options.seam_weight;
        for _ in 0..ctx.options.seam_sweeps {
            let previous = self.label.clone();
            for r in 0..eh {
                for c in 0..ew {
                    let cell = r * ew + c;
                    if previous[cell] == u8::MAX {
                        continue;
                    }
                    let mut best = (f32::INFINITY, previous[cell]);
                    for j in 0..k {
                        let own = self.cost[cell * k + j];
                        if !own.is_finite() {
                            continue;
                        }
                        let mut e = own;
                        for (dc, dr) in [(-1isize, 0isize), (1, 0), (0, -1), (0, 1)] {
                            let (nc, nr) = (c as isize + dc, r as isize + dr);
                            if nc < 0 || nr < 0 || nc >= ew as isize || nr >= eh as isize {
                                continue;
                            }
                            let nb = nr as usize * ew + nc as usize;
                            let other = previous[nb];
                            if other == u8::MAX || other as usize == j {
                                continue;
                            }
                            e += lambda
                                * (SEAM_BASE_COST
                                    + self.disagreement(cell, j, other as usize)
                                    + self.disagreement(nb, j, other as usize));
                        }
                        if e < best.0 {
                            best = (e, j as u8);
                        }
                    }
                    self.label[cell] = best.1;
                }
            }
        }
    }

    /// Mean absolute colour difference of two candidates at a cell, 0–1; 1 where one does not
    /// see it.
    fn disagreement(&self, cell: usize, a: usize, b: usize) -> f32 {
        let k = self.cands.len();
        if !(self.cost[cell * k + a].is_finite() && self.cost[cell * k + b].is_finite()) {
            return 1.0;
        }
        let (ca, cb) = (self.colour[cell * k + a], self.colour[cell * k + b]);
        ((ca[0] - cb[0]).abs() + (ca[1] - cb[1]).abs() + (ca[2] - cb[2]).abs()) / (3.0 * 255.0)
    }

    /// Paints the core's ortho cells into `out` (the band of ortho rows starting at
    /// `band_row0`); returns how many it painted.
    fn paint(
        &self,
        ctx: &Context<'_>,
        out: &mut [u8],
        band_row0: usize,
        jumps: &mut JumpSums,
    ) -> usize {
        let mut painted = 0;
        let mut band = BandPixels {
            rgba: out,
            row0: band_row0,
            width: ctx.lattice.width() * ctx.options.factor,
        };
        let k = self.cands.len();
        let ew = self.width();
        let mut weights = vec![0.0f32; k];
        for row in self.core.1..self.core.3 {
            for col in self.core.0..self.core.2 {
                let (c, r) = (col - self.ext.0, row - self.ext.1);
                let cell = r * ew + c;
                if self.label[cell] == u8::MAX {
                    continue;
                }
                self.feather_weights(ctx, (c, r), &mut weights);
                let on_seam = weights.iter().filter(|w| **w > 0.0).count() > 1;
                painted += self.paint_cell(ctx, (col, row), &weights, &mut band);
                self.add_jumps(ctx, (col, row), on_seam, &band, jumps);
            }
        }
        painted
    }

    /// Feathering weights of tile cell (c, r): how often each view paints the window around
    /// the cell, among the views that see this cell.
    fn feather_weights(&self, ctx: &Context<'_>, (c, r): (usize, usize), weights: &mut [f32]) {
        let k = self.cands.len();
        let ew = self.width();
        let eh = self.ext.3 - self.ext.1;
        let fe = ctx.options.feather as isize;
        let cell = r * ew + c;
        weights.iter_mut().for_each(|w| *w = 0.0);
        for dr in -fe..=fe {
            for dc in -fe..=fe {
                let (nc, nr) = (c as isize + dc, r as isize + dr);
                if nc < 0 || nr < 0 || nc >= ew as isize || nr >= eh as isize {
                    continue;
                }
                let lab = self.label[nr as usize * ew + nc as usize];
                if lab != u8::MAX && self.cost[cell * k + lab as usize].is_finite() {
                    weights[lab as usize] += 1.0;
                }
            }
        }
    }

    /// Paints the ortho cells of DEM cell (col, row) with the views' colours blended by
    /// `weights`; returns how many it painted (those no weighted view sees stay unpainted).
    fn paint_cell(
        &self,
        ctx: &Context<'_>,
        (col, row): (usize, usize),
        weights: &[f32],
        band: &mut BandPixels<'_>,
    ) -> usize {
        let l = ctx.lattice;
        let f = ctx.options.factor;
        let sub = 1.0 / f as f64;
        let mut painted = 0;
        for sr in 0..f {
            for sc in 0..f {
                let (x, y) = (
                    l.west() + (col as f64 + (sc as f64 + 0.5) * sub) * l.cell_width(),
                    l.north() - (row as f64 + (sr as f64 + 0.5) * sub) * l.cell_height(),
                );
                let p = Vector3::new(x, y, ctx.height_at(x, y));
                let (sum, wsum) = self.blend(ctx, &p, weights);
                if wsum == 0.0 {
                    continue;
                }
                let orow = row * f + sr - band.row0;
                let i = (orow * band.width + col * f + sc) * 4;
                for b in 0..3 {
                    band.rgba[i + b] = (sum[b] / wsum).round().clamp(0.0, 255.0) as u8;
                }
                band.rgba[i + 3] = 255;
                painted += 1;
            }
        }
        painted
    }

    /// The weighted sum of the colours (gains applied) of the views with a weight that see
    /// ground point `p`, and the sum of their weights.
    fn blend(&self, ctx: &Context<'_>, p: &Vector3<f64>, weights: &[f32]) -> ([f32; 3], f32) {
        let (mut sum, mut wsum) = ([0.0f32; 3], 0.0f32);
        for j in 0..self.cands.len() {
            if weights[j] == 0.0 {
                continue;
            }
            let v = &ctx.views[self.cands[j]];
            let pc = v.view.cam_from_world.transform_point(p);
            let Ok(px) = v.view.camera.project(&pc) else {
                continue;
            };
            let cam = &v.view.camera;
            if !(pc.z > 0.0
                && px.x >= 0.5
                && px.y >= 0.5
                && px.x <= cam.width() as f64 - 0.5
                && px.y <= cam.height() as f64 - 0.5)
            {
                continue;
            }
            let Some(rgb) = sample(&self.images[j], &px, ctx.options.black_is_nodata) else {
                continue;
            };
            let rgb = apply_gain(rgb, &self.gains[j]);
            for b in 0..3 {
                sum[b] += weights[j] * rgb[b];
            }
            wsum += weights[j];
        }
        (sum, wsum)
    }

    /// Adds the colour steps from DEM cell (col, row)'s ortho cells to their west and north
    /// neighbours' (already painted when they lie in this band): on a seam where the two DEM
    /// cells' views differ, in the interior where no other view is within the feather.
    fn add_jumps(
        &self,
        ctx: &Context<'_>,
        (col, row): (usize, usize),
        on_seam: bool,
        band: &BandPixels<'_>,
        jumps: &mut JumpSums,
    ) {
        let f = ctx.options.factor;
        let (ow, band_row0, out) = (band.width, band.row0, &*band.rgba);
        let ew = self.width();
        let (c, r) = (col - self.ext.0, row - self.ext.1);
        let cell = r * ew + c;
        let label = self.label[cell];
        let mut step = |a: usize, b: usize, other: u8| {
            if out[a + 3] != 255 || out[b + 3] != 255 {
                return;
            }
            let d = (0..3)
                .map(|q| (out[a + q] as f64 - out[b + q] as f64).abs())
                .sum::<f64>()
                / 3.0;
            if other != label && other != u8::MAX {
                jumps.seam += d;
                jumps.seam_n += 1;
            } else if !on_seam {
                jumps.interior += d;
                jumps.interior_n += 1;
            }
        };
        if c > 0 {
            for sr in 0..f {
                let a = ((row * f + sr - band_row0) * ow + col * f) * 4;
                step(a, a - 4, self.label[cell - 1]);
            }
        }
        if r > 0 && row * f > band_row0 {
            for sc in 0..f {
                let a = ((row * f - band_row0) * ow + col * f + sc) * 4;
                step(a, a - ow * 4, self.label[cell - ew]);
            }
        }
    }
}

/// The band of ortho rows a tile paints into: RGBA, `width` cells per row, from ortho row
/// `row0`.
struct BandPixels<'o> {
    rgba: &'o mut [u8],
    row0: usize,
    width: usize,
}

fn apply_gain(rgb: [f32; 3], gain: &[f64; 3]) -> [f32; 3] {
    [
        (rgb[0] as f64 * gain[0]) as f32,
        (rgb[1] as f64 * gain[1]) as f32,
        (rgb[2] as f64 * gain[2]) as f32,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Skipping the blocks the ray passes above gives the plain march's answer, on rough
        /// ground with walls, holes (NaN) and rays in every direction, rising or falling.
        #[test]
        fn skipping_blocks_answers_as_the_plain_march(
            seed in 0u64..1_000,
            (width, height) in (5usize..40, 5usize..40),
            cell in 0.05f64..3.0,
        ) {
            let mut rng = timesift_core::SeededRng::new(seed);
            let lattice = Lattice::new(350_000.0, 5_080_000.0, cell, width, height).unwrap();
            let heights: Vec<f32> = (0..width * height)
                .map(|_| match rng.uniform() {
                    u if u < 0.05 => f32::NAN,
                    u if u < 0.1 => (10.0 + 20.0 * rng.uniform() * cell) as f32,
                    _ => (rng.uniform() * 2.0 * cell) as f32,
                })
                .collect();
            let max_height = heights
                .iter()
                .filter(|h| h.is_finite())
                .fold(f64::NEG_INFINITY, |m, &h| m.max(h as f64));
            let ctx = Context {
                lattice: &lattice,
                heights: &heights,
                max_height,
                blocks: BlockMax::new(&heights, width, height),
                views: Vec::new(),
                options: OrthoOptions::default(),
            };
            // The plain march: blocks of infinite height, which the ray never passes above,
            // so no sample is skipped.
            let plain = Context {
                blocks: BlockMax {
                    columns: ctx.blocks.columns,
                    heights: vec![f32::INFINITY; ctx.blocks.heights.len()],
                },
                views: Vec::new(),
                ..ctx
            };
            let (w, h) = (width as f64 * cell, height as f64 * cell);
            let mut hidden = 0;
            for _ in 0..200 {
                let p = Vector3::new(
                    350_000.0 + rng.uniform() * w,
                    5_080_000.0 - rng.uniform() * h,
                    rng.uniform() * 2.0 * cell,
                );
                let c = Vector3::new(
                    350_000.0 + (rng.uniform() * 3.0 - 1.0) * w,
                    5_080_000.0 - (rng.uniform() * 3.0 - 1.0) * h,
                    (rng.uniform() * 2.0 - 0.5) * 40.0 * cell,
                );
                let expected = plain.occluded(&p, &c);
                prop_assert_eq!(ctx.occluded(&p, &c), expected, "p {:?} c {:?}", p, c);
                hidden += usize::from(expected);
            }
            // Both answers occur, so the comparison says something.
            prop_assert!(hidden > 0 && hidden < 200, "{} of 200 hidden", hidden);
        }
    }
}
