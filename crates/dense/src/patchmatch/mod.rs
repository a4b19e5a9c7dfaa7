//! PatchMatch multi-view stereo with slanted planes, in the manner of ACMH/ACMM (Xu & Tao 2019):
//! per pixel a plane (depth + normal) in the reference camera frame, refined by red–black
//! checkerboard propagation with adaptive multi-hypothesis sampling, per-pixel joint view
//! selection, bilateral-weighted NCC over a sparse window, random refinement; coarse to fine
//! over an image pyramid with a geometric-consistency term that uses the source views' own
//! depth maps.
//!
//! The work of an epoch is a [`schedule`] of passes. Every pass runs over every view and needs
//! the previous pass's maps (its own, and its sources' for the geometric term), so the caller
//! runs pass by pass, caching each view's result: that is what makes the dense stage resumable
//! image by image and its memory bounded by one reference and its sources.
//!
//! Schedule for a pyramid of S + 1 scales (S from the image size, [`PatchMatchOptions`]):
//! photometric at the coarsest scale from random planes, one geometric pass there; then for
//! each finer scale, a hierarchy pass (the coarser planes upsampled by joint bilateral
//! upsampling, refined photometrically, kept unless a new plane is clearly better: ACMM's
//! detail restorer) and a geometric pass. When the plan refines (working images at half the
//! requested level, [`crate::plan::EpochPlan::refined_scales`]), those passes stop at scale 1
//! (the requested level) and a refinement pass follows at scale 0: the planes upsampled, and
//! matched again only where the coarser map was poor ([`refine::refine_selection`]) or its
//! upsampled plane is unusable; its geometric pass updates only the pixels not marked
//! upsampled.

mod board;
pub mod cost;
pub(crate) mod fast_exp;
pub mod refine;
mod update;
pub mod upsample;

use rayon::prelude::*;
use timesift_core::SeededRng;

use crate::DenseError;
use crate::camera::WorkingCamera;
use crate::depth_map::DepthMap;
use crate::filter::camera_of_map;
use crate::image::{Mask, Plane, WorkingImage};
use crate::plan::{EpochPlan, ViewPlan};
use board::{Board, Colour, PixelState};
use cost::{PlaneWarp, RefCamera, SourceView, WindowShape};
use refine::{RefineOptions, refine_selection};
use update::{MAX_SOURCES, PassContext, Scratch, random_normal};

/// Options of the PatchMatch passes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchMatchOptions {
    /// Half-size of the NCC window, pixels (5: an 11 × 11 window).
    pub window_radius: usize,
    /// Step between window samples (2: every other pixel, the sparse window).
    pub window_step: usize,
    /// Intensity σ of the bilateral weights (intensities 0–1). 0.1, between ACMM's (3 of 255,
    /// 0.012) and COLMAP's (0.2). Smaller keeps a roof's depth out of the shadow beside it on
    /// clean digital images, but weighs a scanned film's grain as if it were an edge: at 0.04
    /// the `archival` scene's 1971 scans lost 15 points of completeness.
    pub sigma_color: f32,
    /// Iterations of photometric and hierarchy passes.
    pub photometric_iterations: usize,
    /// Iterations of geometric passes.
    pub geometric_iterations: usize,
    /// Iterations of a refinement pass, and at most as many of the geometric pass after it
    /// (3, as the photometric passes). Fewer is cheaper: one took 1.3–1.7 times less CPU on
    /// the synthetic scenes at the same median, 90th percentile and completeness, but left
    /// narrow tree crowns biased (a test's crowns: −0.21 m at one, −0.14 m at two, against
    /// −0.27 m unrefined) — the refinement exists for them.
    pub refine_iterations: usize,
    /// Weight λ of the geometric term in geometric passes (ACMM: 0.2).
    pub geometric_weight: f32,
    /// Truncation of the geometric term, pixels (ACMM: 3).
    pub geometric_max_px: f32,
    /// The coarsest scale is the first whose longer side is at most this many pixels.
    pub coarsest_size: usize,
    /// Most pyramid scales (besides the refined ones of a plan that refines).
    pub max_scales: usize,
    /// Relative depth perturbation of the refinement (ACMH: 0.02).
    pub depth_perturbation: f32,
    /// Normal perturbation of the refinement, radians (ACMH: 0.01 π).
    pub normal_perturbation: f32,
    /// Seed of every random draw.
    pub seed: u64,
    /// Where a refinement pass matches again (plans that refine).
    pub refine: RefineOptions,
}

impl Default for PatchMatchOptions {
    fn default() -> Self {
        PatchMatchOptions {
            window_radius: 5,
            window_step: 2,
            sigma_color: 0.1,
            photometric_iterations: 3,
            geometric_iterations: 2,
            refine_iterations: 3,
            geometric_weight: 0.2,
            geometric_max_px: 3.0,
            coarsest_size: 400,
            max_scales: 4,
            depth_perturbation: 0.02,
            normal_perturbation: 0.01 * std::f32::consts::PI,
            seed: 1,
            refine: RefineOptions::default(),
        }
    }
}

impl PatchMatchOptions {
    /// Checks every option's domain.
    pub fn validate(&self) -> Result<(), DenseError> {
        let bad = |what: &str| Err(DenseError::InvalidOption(what.to_string()));
        if self.window_radius == 0 || self.window_radius > 15 {
            return bad("window_radius: expected 1 to 15 pixels");
        }
        if self.window_step == 0 || self.window_step > self.window_radius {
            return bad("window_step: expected 1 to window_radius");
        }
        if !(self.sigma_color > 0.0) {
            return bad("sigma_color: expected a positive number");
        }
        if self.photometric_iterations == 0 || self.refine_iterations == 0 {
            return bad("photometric_iterations and refine_iterations: expected at least 1");
        }
        if !(self.geometric_weight >= 0.0) || !(self.geometric_max_px > 0.0) {
            return bad("geometric_weight ≥ 0 and geometric_max_px > 0 expected");
        }
        if self.coarsest_size < 32 || self.max_scales == 0 {
            return bad("coarsest_size ≥ 32 and max_scales ≥ 1 expected");
        }
        if !(self.depth_perturbation > 0.0 && self.depth_perturbation < 1.0) {
            return bad("depth_perturbation: expected a fraction in (0, 1)");
        }
        if !(self.normal_perturbation > 0.0) {
            return bad("normal_perturbation: expected a positive angle");
        }
        self.refine.validate()
    }
}

/// What a pass does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PassKind {
    /// From random planes, photometric cost only.
    Photometric,
    /// From the previous (coarser) pass upsampled, photometric, with the detail restorer.
    Hierarchy,
    /// From the previous pass at the same scale, photometric plus geometric consistency with
    /// the sources' maps of the previous pass.
    Geometric,
    /// From the previous (coarser) pass upsampled, like a hierarchy pass, but matched again
    /// only at the pixels [`refine::refine_selection`] picks; the others keep the upsampled
    /// plane and are marked [`DepthMap::upsampled`].
    Refine,
}

/// One pass over every view of an epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Pass {
    /// What the pass does.
    pub kind: PassKind,
    /// Pyramid scale (0: the working resolution; s: halved s times).
    pub scale: usize,
    /// Checkerboard iterations (each a black and a red half-pass).
    pub iterations: usize,
}

/// The passes for an epoch whose largest working image is `max_side` pixels long, the finest
/// `refined_scales` of them refinement passes (the scales above are scheduled as they would be
/// for a working image that many times halved). With `geometric_iterations > 0`, every scale
/// ends with a geometric pass; after a refinement it updates only the pixels not marked
/// upsampled (those it matched, and any left without a depth).
pub fn schedule(max_side: usize, refined_scales: usize, options: &PatchMatchOptions) -> Vec<Pass> {
    let mut coarsest = refined_scales;
    let mut side = max_side >> refined_scales;
    while side > options.coarsest_size && coarsest + 1 < options.max_scales + refined_scales {
        side /= 2;
        coarsest += 1;
    }
    // Per scale, coarse to fine: what starts it, then its geometric pass.
    let kinds = std::iter::once((PassKind::Photometric, coarsest))
        .chain(
            (refined_scales..coarsest)
                .rev()
                .map(|s| (PassKind::Hierarchy, s)),
        )
        .chain((0..refined_scales).rev().map(|s| (PassKind::Refine, s)));
    let mut passes = Vec::new();
    for (kind, scale) in kinds {
        let (p, g) = match kind {
            PassKind::Refine => (
                options.refine_iterations,
                options.geometric_iterations.min(options.refine_iterations),
            ),
            _ => (options.photometric_iterations, options.geometric_iterations),
        };
        passes.push(Pass {
            kind,
            scale,
            iterations: p,
        });
        if g > 0 {
            passes.push(Pass {
                kind: PassKind::Geometric,
                scale,
                iterations: g,
            });
        }
    }
    passes
}

/// The schedule of a plan (from its largest working image).
pub fn plan_schedule(plan: &EpochPlan, options: &PatchMatchOptions) -> Vec<Pass> {
    let max_side = plan
        .views
        .iter()
        .map(|v| v.camera.width.max(v.camera.height))
        .max()
        .unwrap_or(0);
    schedule(max_side, plan.refined_scales, options)
}

/// The images and maps one view's pass reads.
pub struct PassInput<'a> {
    /// The view's working image.
    pub reference: &'a WorkingImage,
    /// Its sources' working images, in the order of the plan's sources.
    pub sources: &'a [&'a WorkingImage],
    /// The view's map from the previous pass (none for the first pass).
    pub previous: Option<&'a DepthMap>,
    /// The sources' maps from the previous pass (geometric passes; `None` for a source whose
    /// map is missing, which then contributes the truncated geometric cost).
    pub source_maps: &'a [Option<&'a DepthMap>],
}

/// An image halved `scale` times, with its mask.
pub fn image_at_scale(image: &WorkingImage, scale: usize) -> (Plane, Mask) {
    let mut grey = image.grey.clone();
    let mut mask = image.mask.clone();
    for _ in 0..scale {
        grey = grey.half();
        mask = mask.half();
    }
    (grey, mask)
}

fn to_f32_rt(pose: &timesift_core::Pose) -> ([f32; 9], [f32; 3]) {
    let r = pose.rotation_matrix();
    let mut rr = [0.0f32; 9];
    for i in 0..3 {
        for j in 0..3 {
            rr[i * 3 + j] = r[(i, j)] as f32;
        }
    }
    let t = pose.translation;
    (rr, [t.x as f32, t.y as f32, t.z as f32])
}

/// Runs pass `pass` (an entry of the epoch's schedule, at index `pass_index`) for view `view`.
/// A view without sources gets an empty map.
pub fn run_pass(
    plan: &EpochPlan,
    view: usize,
    pass_index: usize,
    pass: &Pass,
    input: &PassInput<'_>,
    options: &PatchMatchOptions,
) -> Result<DepthMap, DenseError> {
    options.validate()?;
    let vp = plan
        .views
        .get(view)
        .ok_or_else(|| DenseError::InvalidInput(format!("no view {view} in the plan")))?;
    let camera = vp.camera.at_scale(pass.scale);
    if vp.sources.is_empty() {
        return Ok(DepthMap::empty(camera.width, camera.height));
    }
    check_pass_input(plan, view, pass, input)?;
    let geometric = pass.kind == PassKind::Geometric;
    let (grey, mask) = image_at_scale(input.reference, pass.scale);
    let source_images: Vec<(Plane, Mask)> = input
        .sources
        .iter()
        .map(|image| image_at_scale(image, pass.scale))
        .collect();
    let shape = window_shape(options)?;
    let k_ref = RefCamera::of(&camera);
    let sources = source_views(plan, view, pass, input, &source_images);
    let warps = sources.iter().map(|s| PlaneWarp::new(s, &k_ref)).collect();
    let ctx = PassContext {
        shape: &shape,
        grey: &grey,
        mask: &mask,
        k_ref,
        sources,
        warps,
        depth_range: (vp.depth_range.0 as f32, vp.depth_range.1 as f32),
        geometric_weight: if geometric {
            options.geometric_weight
        } else {
            0.0
        },
        geometric_max_px: options.geometric_max_px,
        hierarchy: matches!(pass.kind, PassKind::Hierarchy | PassKind::Refine),
        depth_perturbation: options.depth_perturbation,
        normal_perturbation: options.normal_perturbation,
        seed: pixel_pass_seed(options.seed, view, pass_index),
    };
    let start = starting_planes(&ctx, vp, pass, input, &camera)?;
    let mut board = Board::new(camera.width, camera.height);
    initialise(&ctx, &mut board, &start);
    let selected = pixels_to_match(&ctx, vp, pass, input, &start, options);
    for iteration in 0..pass.iterations {
        for colour in Colour::BOTH {
            half_pass(&ctx, &mut board, colour, iteration, selected.as_deref());
        }
    }
    let mut map = median_filtered(&board, selected.as_deref());
    if let Some(selected) = &selected {
        for ((up, &chosen), &d) in map.upsampled.iter_mut().zip(selected).zip(&map.depth) {
            *up = !chosen && d > 0.0;
        }
    }
    Ok(map)
}

/// Checks that a pass of `view` (which has sources) is given one image per source, each of its
/// view's working size, and for a geometric pass one depth map per source.
fn check_pass_input(
    plan: &EpochPlan,
    view: usize,
    pass: &Pass,
    input: &PassInput<'_>,
) -> Result<(), DenseError> {
    let vp = &plan.views[view];
    if vp.sources.len() > MAX_SOURCES {
        return Err(DenseError::InvalidOption(format!(
            "{} sources: at most {MAX_SOURCES}",
            vp.sources.len()
        )));
    }
    if input.sources.len() != vp.sources.len() {
        return Err(DenseError::InvalidInput(format!(
            "view {view}: {} source images given for {} sources",
            input.sources.len(),
            vp.sources.len()
        )));
    }
    let check_size = |image: &WorkingImage, cam: &WorkingCamera| {
        if image.width() != cam.width || image.height() != cam.height {
            Err(DenseError::ImageSize {
                expected: (cam.width, cam.height),
                found: (image.width(), image.height()),
            })
        } else {
            Ok(())
        }
    };
    check_size(input.reference, &vp.camera)?;
    for (s, image) in vp.sources.iter().zip(input.sources) {
        check_size(image, &plan.views[s.view].camera)?;
    }
    if pass.kind == PassKind::Geometric && input.source_maps.len() != vp.sources.len() {
        return Err(DenseError::InvalidInput(format!(
            "view {view}: {} source depth maps given for {} sources",
            input.source_maps.len(),
            vp.sources.len()
        )));
    }
    Ok(())
}

/// The source views of `view` at the pass's scale: images, cameras, the reference-to-source
/// transform, and in a geometric pass the source's own depth map.
fn source_views<'a>(
    plan: &'a EpochPlan,
    view: usize,
    pass: &Pass,
    input: &PassInput<'a>,
    images: &'a [(Plane, Mask)],
) -> Vec<SourceView<'a>> {
    let vp = &plan.views[view];
    let geometric = pass.kind == PassKind::Geometric;
    let local_from_ref = vp.cam_from_local.inverse();
    vp.sources
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let sp = &plan.views[s.view];
            let (r, t) = to_f32_rt(&(sp.cam_from_local * local_from_ref));
            let depth = if geometric {
                input.source_maps[k].and_then(|m| {
                    camera_of_map(&sp.camera, m.width, m.height).map(|c| (m.depth.as_slice(), c))
                })
            } else {
                None
            };
            SourceView {
                grey: &images[k].0,
                mask: &images[k].1,
                camera: sp.camera.at_scale(pass.scale),
                r,
                t,
                depth,
            }
        })
        .collect()
}

/// The NCC window of the options.
fn window_shape(options: &PatchMatchOptions) -> Result<WindowShape, DenseError> {
    WindowShape::new(
        options.window_radius,
        options.window_step,
        options.window_radius as f32,
        options.sigma_color,
    )
    .ok_or_else(|| {
        DenseError::InvalidOption(format!(
            "window_radius {} with window_step {}: more than {} samples",
            options.window_radius,
            options.window_step,
            cost::MAX_WINDOW
        ))
    })
}

/// Pixels matched at this scale (`None`: every one): in a refinement those it picks, and those
/// whose upsampled plane is unusable (they start from a random plane, which must be matched);
/// in the geometric pass after a refinement, the pixels the refinement matched.
fn pixels_to_match(
    ctx: &PassContext<'_>,
    vp: &ViewPlan,
    pass: &Pass,
    input: &PassInput<'_>,
    start: &(Vec<f32>, Vec<[f32; 3]>),
    options: &PatchMatchOptions,
) -> Option<Vec<bool>> {
    let camera = vp.camera.at_scale(pass.scale);
    match (pass.kind, input.previous) {
        (PassKind::Refine, Some(coarse)) => {
            let mut picked = refine_selection(
                coarse,
                &vp.camera.at_scale(pass.scale + 1),
                camera.width,
                camera.height,
                &options.refine,
            );
            for (k, p) in picked.iter_mut().enumerate() {
                *p = *p || !usable_start(ctx, start, k % camera.width, k / camera.width);
            }
            Some(picked)
        }
        (PassKind::Geometric, Some(previous)) if previous.upsampled.iter().any(|&u| u) => {
            Some(previous.upsampled.iter().map(|&u| !u).collect())
        }
        _ => None,
    }
}

fn pixel_pass_seed(seed: u64, view: usize, pass_index: usize) -> u64 {
    update::pixel_seed(seed, 1_000_003, view, pass_index)
}

/// Starting (depth, normal) per pixel: random, upsampled or carried over; depth 0 draws a
/// random plane.
fn starting_planes(
    ctx: &PassContext<'_>,
    vp: &ViewPlan,
    pass: &Pass,
    input: &PassInput<'_>,
    camera: &WorkingCamera,
) -> Result<(Vec<f32>, Vec<[f32; 3]>), DenseError> {
    let n = camera.width * camera.height;
    match pass.kind {
        PassKind::Photometric => Ok((vec![0.0; n], vec![[0.0; 3]; n])),
        PassKind::Geometric | PassKind::Hierarchy | PassKind::Refine => {
            let previous = input.previous.ok_or_else(|| {
                DenseError::InvalidInput(format!(
                    "a {:?} pass needs the view's map of the previous pass",
                    pass.kind
                ))
            })?;
            let prev_camera = camera_of_map(&vp.camera, previous.width, previous.height)
                .ok_or_else(|| {
                    DenseError::InvalidInput(format!(
                        "a depth map of {} × {} pixels fits no scale of a {} × {} view",
                        previous.width, previous.height, vp.camera.width, vp.camera.height
                    ))
                })?;
            if !previous.is_consistent() {
                return Err(DenseError::InvalidInput(
                    "a depth map's channels differ in length".into(),
                ));
            }
            if pass.kind == PassKind::Geometric {
                if prev_camera.width != camera.width {
                    return Err(DenseError::InvalidInput(
                        "a geometric pass continues a map of its own scale".into(),
                    ));
                }
                Ok((previous.depth.clone(), previous.normal.clone()))
            } else {
                let (coarse_grey, _) = image_at_scale(input.reference, pass.scale + 1);
                if coarse_grey.width != previous.width || coarse_grey.height != previous.height {
                    return Err(DenseError::InvalidInput(
                        "a hierarchy pass continues a map of the next coarser scale".into(),
                    ));
                }
                Ok(upsample::upsample(
                    previous,
                    &coarse_grey,
                    &RefCamera::of(&prev_camera),
                    ctx.grey,
                    &ctx.k_ref,
                ))
            }
        }
    }
}

/// Whether pixel (x, y)'s starting plane is usable: in the depth range and facing the camera
/// (else [`initialise`] draws a random plane).
fn usable_start(
    ctx: &PassContext<'_>,
    (depth, normal): &(Vec<f32>, Vec<[f32; 3]>),
    x: usize,
    y: usize,
) -> bool {
    let i = y * ctx.grey.width + x;
    let ray = ctx.k_ref.ray(x as f32 + 0.5, y as f32 + 0.5);
    let facing = normal[i][0] * ray[0] + normal[i][1] * ray[1] + normal[i][2] * ray[2] < 0.0;
    depth[i] >= ctx.depth_range.0 && depth[i] <= ctx.depth_range.1 && facing
}

/// Fills the board from the starting planes (random where there is none), with each plane's
/// cost over its best views.
fn initialise(ctx: &PassContext<'_>, board: &mut Board, start: &(Vec<f32>, Vec<[f32; 3]>)) {
    let (width, half_width) = (board.width, board.half_width);
    let (depth, normal) = start;
    for colour in Colour::BOTH {
        board.cells[colour.index()]
            .par_chunks_mut(half_width)
            .enumerate()
            .for_each_init(
                || Scratch::new(ctx.shape),
                |scratch, (y, row)| {
                    for (k, cell) in row.iter_mut().enumerate() {
                        let x = Board::column(colour, y, k);
                        if x >= width || !ctx.mask.at(x, y) {
                            *cell = PixelState::NONE;
                            continue;
                        }
                        let i = y * width + x;
                        let ray = ctx.k_ref.ray(x as f32 + 0.5, y as f32 + 0.5);
                        let (d, n) = if usable_start(ctx, start, x, y) {
                            (depth[i], normal[i])
                        } else {
                            let mut rng =
                                SeededRng::new(update::pixel_seed(ctx.seed, usize::MAX, x, y));
                            let d = rng
                                .uniform_range(ctx.depth_range.0 as f64, ctx.depth_range.1 as f64)
                                as f32;
                            (d, random_normal(&mut rng, &ray))
                        };
                        *cell = ctx.initial_state(scratch, x, y, n, d);
                    }
                },
            );
    }
}

/// Updates every pixel of one colour (or only those `selected`), rows in parallel.
fn half_pass(
    ctx: &PassContext<'_>,
    board: &mut Board,
    colour: Colour,
    iteration: usize,
    selected: Option<&[bool]>,
) {
    let (width, half_width) = (board.width, board.half_width);
    let (mine, other) = board.split(colour);
    mine.par_chunks_mut(half_width).enumerate().for_each_init(
        || Scratch::new(ctx.shape),
        |scratch, (y, row)| {
            for (k, cell) in row.iter_mut().enumerate() {
                let x = Board::column(colour, y, k);
                if x < width && selected.is_none_or(|s| s[y * width + x]) {
                    ctx.update(&other, scratch, cell, x, y, iteration);
                }
            }
        },
    );
}

/// Neighbours of ACMH's depth median filter (dx, dy), besides the pixel itself.
const MEDIAN_NEIGHBOURS: [(i64, i64); 20] = [
    (0, -1),
    (0, 1),
    (0, -3),
    (0, 3),
    (0, -5),
    (0, 5),
    (-1, 0),
    (1, 0),
    (-3, 0),
    (3, 0),
    (-5, 0),
    (5, 0),
    (-2, -1),
    (2, -1),
    (-2, 1),
    (2, 1),
    (-1, -2),
    (1, -2),
    (-1, 2),
    (1, 2),
];
/// Pixels matched better than this keep their depth through the median filter.
const MEDIAN_KEEP_COST: f32 = 0.001;

/// The final map of a pass: depths through ACMH's sparse median filter (removing isolated
/// outliers inside smooth regions), normals and costs as they are. Pixels the pass did not
/// match (outside `selected`) keep their plane's depth: it was filtered at its own scale.
fn median_filtered(board: &Board, selected: Option<&[bool]>) -> DepthMap {
    let (w, h) = (board.width, board.height);
    let mut map = DepthMap::empty(w, h);
    for y in 0..h {
        for x in 0..w {
            let s = board.get(x, y);
            if s.depth > 0.0 && s.cost < cost::WORST {
                let i = y * w + x;
                map.depth[i] = s.depth;
                map.normal[i] = s.n;
                map.cost[i] = s.cost;
            }
        }
    }
    let depths = &map.depth;
    let costs = &map.cost;
    let filtered: Vec<f32> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).map(move |x| {
                let i = y * w + x;
                let d = depths[i];
                let matched = selected.is_none_or(|s| s[i]);
                if !(d > 0.0) || costs[i] < MEDIAN_KEEP_COST || !matched {
                    return d;
                }
                let mut values = [0.0f32; 21];
                values[0] = d;
                let mut count = 1;
                for (dx, dy) in MEDIAN_NEIGHBOURS {
                    let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                    if xx >= 0 && yy >= 0 && (xx as usize) < w && (yy as usize) < h {
                        let v = depths[yy as usize * w + xx as usize];
                        if v > 0.0 {
                            values[count] = v;
                            count += 1;
                        }
                    }
                }
                let values = &mut values[..count];
                values.sort_by(f32::total_cmp);
                if count % 2 == 1 {
                    values[count / 2]
                } else {
                    0.5 * (values[count / 2 - 1] + values[count / 2])
                }
            })
        })
        .collect();
    map.depth = filtered;
    map
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_goes_coarse_to_fine() {
        let options = PatchMatchOptions::default();
        let passes = schedule(1500, 0, &options);
        // 1500 → 750 → 375: three scales.
        let kinds: Vec<(PassKind, usize)> = passes.iter().map(|p| (p.kind, p.scale)).collect();
        assert_eq!(
            kinds,
            vec![
                (PassKind::Photometric, 2),
                (PassKind::Geometric, 2),
                (PassKind::Hierarchy, 1),
                (PassKind::Geometric, 1),
                (PassKind::Hierarchy, 0),
                (PassKind::Geometric, 0),
            ]
        );
        assert_eq!(schedule(300, 0, &options).len(), 2);
    }

    #[test]
    fn a_refining_schedule_runs_the_same_passes_one_scale_up_then_refines() {
        let options = PatchMatchOptions::default();
        let kinds = |max_side: usize, refined: usize| -> Vec<(PassKind, usize)> {
            schedule(max_side, refined, &options)
                .iter()
                .map(|p| (p.kind, p.scale))
                .collect()
        };
        // Working images of 3000 pixels refined once: the 1500-pixel schedule at scales 1–3.
        let plain: Vec<(PassKind, usize)> = kinds(1500, 0)
            .into_iter()
            .map(|(k, s)| (k, s + 1))
            .collect();
        let mut expected = plain;
        expected.extend([(PassKind::Refine, 0), (PassKind::Geometric, 0)]);
        assert_eq!(kinds(3000, 1), expected);
        assert_eq!(
            kinds(600, 1),
            vec![
                (PassKind::Photometric, 1),
                (PassKind::Geometric, 1),
                (PassKind::Refine, 0),
                (PassKind::Geometric, 0),
            ]
        );
        // The refinement and its geometric pass run `refine_iterations` (the geometric one at
        // most `geometric_iterations`); the other passes their own counts.
        let options = PatchMatchOptions {
            photometric_iterations: 3,
            geometric_iterations: 2,
            refine_iterations: 1,
            ..PatchMatchOptions::default()
        };
        let iterations: Vec<usize> = schedule(600, 1, &options)
            .iter()
            .map(|p| p.iterations)
            .collect();
        assert_eq!(iterations, vec![3, 2, 1, 1]);
        let options = PatchMatchOptions {
            geometric_iterations: 0,
            refine_iterations: 2,
            ..options
        };
        let passes = schedule(600, 1, &options);
        let iterations: Vec<(PassKind, usize)> =
            passes.iter().map(|p| (p.kind, p.iterations)).collect();
        assert_eq!(
            iterations,
            vec![(PassKind::Photometric, 3), (PassKind::Refine, 2)]
        );
    }
}
