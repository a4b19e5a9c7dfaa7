//! Multi-view stereo of one epoch on frozen orientations: per-view depth maps by PatchMatch with
//! slanted planes, filtering, and fusion into one coloured cloud (step 3 of Time-SIFT).
//!
//! The steps, each a function the caller can run, cache and resume on its own:
//! 1. [`plan::plan_epoch`]: per view, the working pinhole camera at the chosen level (at half
//!    of it when refining), the pose
//!    in a local frame, the source views (shared sparse points, triangulation angle, scale;
//!    every part of the field covered first), the wider set of overlapping views that filtering
//!    and fusion check against, and the depth range (sparse-point depths).
//! 2. [`undistort::UndistortMap`]: each original image resampled to its working camera, with the
//!    pixels that may not produce depths (masks, no-data) marked.
//! 3. [`patchmatch::run_pass`] for each pass of [`patchmatch::plan_schedule`], view by view:
//!    coarse-to-fine PatchMatch (ACMH/ACMM) with a geometric-consistency term; with
//!    [`PlanOptions::refine`] (the default), the working images are at twice the resolution of
//!    the level, the passes stop at the level, and a last refinement matches again only where
//!    the level's maps are poor ([`patchmatch::refine`]: tree crowns, boulders, edges).
//! 4. [`filter::filter_depth_map`]: depths that enough neighbours agree with, good cost, no
//!    speckle.
//! 5. [`fusion::fuse`]: consistent depths of several views merged into points.
//!
//! [`reconstruct_epoch`] chains them in memory for callers with few images (tests, examples).
//!
//! Invariants:
//! - Sees one epoch at a time and never changes an orientation: poses and cameras are inputs.
//! - Reads and writes no file (the root package does, through `timesift-io`); images come in as
//!   decoded buffers, results go out as [`DepthMap`]s and a [`FusedCloud`].
//! - Every random draw is seeded per pixel, and parallel work never reads what it writes, so
//!   results do not depend on the number of threads.
//! - Matching works in f32 in camera frames and a local frame centred on the cameras; world
//!   positions of fused points are computed in f64.
//!
//! # Example
//!
//! Four views of a textured plane rendered by `timesift-synth` from 10 m, oriented exactly;
//! [`reconstruct_epoch`] turns them into a cloud whose points lie on the plane within a
//! fraction of a ground pixel (about 8 cm here).
//!
//! ```
//! use timesift_core::nalgebra::Vector3;
//! use timesift_core::{BrownCamera, Camera, Pose};
//! use timesift_dense::{DenseOptions, EpochInput, ImageView, SparsePoint, View, reconstruct_epoch};
//! use timesift_synth::noise::Noise;
//! use timesift_synth::render::{Material, RenderOptions, Scene, render};
//!
//! let ground = Material::Cover {
//!     noise: Box::new(Noise::new(11)),
//!     dark: Vector3::new(0.25, 0.22, 0.18),
//!     light: Vector3::new(0.7, 0.65, 0.55),
//!     scale: 2.0,
//!     octaves: 7,
//!     contrast: 1.3,
//!     speckle: 0.45,
//!     speckle_seed: 7,
//! };
//! let corners = [(-30.0, -30.0), (30.0, -30.0), (30.0, 30.0), (-30.0, 30.0)];
//! let vertices: Vec<Vector3<f64>> = corners.iter().map(|&(x, y)| Vector3::new(x, y, 0.0)).collect();
//! let scene = Scene::new(&vertices, &[[0, 1, 2], [0, 2, 3]], vec![0, 0], vec![ground])?;
//!
//! let camera = Camera::Brown(BrownCamera::new(160, 120, 128.0)?);
//! let centres = [(-1.5, -1.0), (1.5, -1.0), (-1.5, 1.0), (1.5, 1.0)];
//! let views: Vec<View> = centres
//!     .iter()
//!     .map(|&(x, y)| {
//!         let centre = Vector3::new(x, y, 10.0);
//!         let target = Vector3::new(0.0, 0.001, 0.0);
//!         View { camera: camera.clone(), cam_from_world: Pose::look_at(&centre, &target).unwrap() }
//!     })
//!     .collect();
//! let images: Vec<Vec<f32>> = views
//!     .iter()
//!     .map(|v| {
//!         let image = render(&scene, &camera, 160, 120, &v.cam_from_world, &RenderOptions::default());
//!         image.map(|i| i.data.iter().flatten().copied().collect())
//!     })
//!     .collect::<Result<_, _>>()?;
//! // Tie points, as the orientation would give them: here a grid on the plane seen by all.
//! let points = (0..25)
//!     .map(|k| SparsePoint {
//!         position: Vector3::new((k % 5) as f64 - 2.0, (k / 5) as f64 - 2.0, 0.0),
//!         views: vec![0, 1, 2, 3],
//!     })
//!     .collect();
//! let input = EpochInput { views, points };
//! let pixels: Vec<ImageView> = images
//!     .iter()
//!     .map(|data| ImageView { width: 160, height: 120, channels: 3, data })
//!     .collect();
//! let mut options = DenseOptions::default();
//! options.plan.level = 1;
//! let result = reconstruct_epoch(&input, &pixels, &[None; 4], &options)?;
//!
//! let cloud = &result.cloud;
//! assert!(cloud.len() > 5_000, "{} points", cloud.len());
//! let mut heights: Vec<f64> = cloud.positions.iter().map(|p| p.z.abs()).collect();
//! heights.sort_by(f64::total_cmp);
//! let ground_pixel = 10.0 / 128.0;
//! assert!(heights[heights.len() / 2] < 0.5 * ground_pixel, "{}", heights[heights.len() / 2]);
//! assert!(cloud.images.iter().all(|&n| n >= 3));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs, unnameable_types)]

pub mod camera;
pub mod depth_map;
mod error;
pub mod filter;
pub mod fusion;
pub mod image;
pub mod patchmatch;
pub mod plan;
pub mod undistort;

pub use camera::WorkingCamera;
pub use depth_map::DepthMap;
pub use error::DenseError;
pub use filter::{FilterOptions, filter_depth_map};
pub use fusion::{FusedCloud, FusionOptions, FusionView, fuse};
pub use image::{ImageView, Mask, Plane, WorkingImage};
pub use patchmatch::refine::RefineOptions;
pub use patchmatch::{
    Pass, PassInput, PassKind, PatchMatchOptions, plan_schedule, run_pass, schedule,
};
pub use plan::{EpochInput, EpochPlan, PlanOptions, SparsePoint, View, ViewPlan, plan_epoch};
pub use undistort::{UndistortMap, working_camera};

/// Every option of dense matching.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DenseOptions {
    /// Level, sources.
    pub plan: PlanOptions,
    /// PatchMatch.
    pub patchmatch: PatchMatchOptions,
    /// Depth-map filter.
    pub filter: FilterOptions,
    /// Fusion.
    pub fusion: FusionOptions,
    /// Whether pixels exactly black in every channel are no-data (scan borders).
    pub black_is_nodata: bool,
}

/// The depth maps and fused cloud of one epoch, computed in memory: every working image and
/// every map of a pass are held at once, so this is for small epochs (tests, examples); the
/// `dense` stage runs the same steps view by view with a cache on disk. `images[k]` is the
/// original image of view k, `masks[k]` an optional mask in its pixels.
pub fn reconstruct_epoch(
    input: &EpochInput,
    images: &[ImageView<'_>],
    masks: &[Option<&Mask>],
    options: &DenseOptions,
) -> Result<EpochResult, DenseError> {
    if images.len() != input.views.len() || masks.len() != input.views.len() {
        return Err(DenseError::InvalidInput(format!(
            "{} views, {} images, {} masks",
            input.views.len(),
            images.len(),
            masks.len()
        )));
    }
    let plan = plan_epoch(input, &options.plan)?;
    let working: Vec<WorkingImage> = input
        .views
        .iter()
        .zip(&plan.views)
        .zip(images.iter().zip(masks))
        .map(|((view, vp), (image, mask))| {
            UndistortMap::new(&view.camera, vp.camera, plan.level).apply(
                image,
                *mask,
                options.black_is_nodata,
            )
        })
        .collect::<Result<_, _>>()?;
    let passes = plan_schedule(&plan, &options.patchmatch);
    let mut maps: Vec<Option<DepthMap>> = vec![None; plan.views.len()];
    for (index, pass) in passes.iter().enumerate() {
        let mut next = Vec::with_capacity(plan.views.len());
        for (view, vp) in plan.views.iter().enumerate() {
            let sources: Vec<&WorkingImage> = vp.sources.iter().map(|s| &working[s.view]).collect();
            let source_maps: Vec<Option<&DepthMap>> =
                vp.sources.iter().map(|s| maps[s.view].as_ref()).collect();
            let pass_input = PassInput {
                reference: &working[view],
                sources: &sources,
                previous: maps[view].as_ref(),
                source_maps: &source_maps,
            };
            next.push(Some(run_pass(
                &plan,
                view,
                index,
                pass,
                &pass_input,
                &options.patchmatch,
            )?));
        }
        maps = next;
    }
    let finals: Vec<DepthMap> = maps
        .into_iter()
        .zip(&plan.views)
        .map(|(m, vp)| m.unwrap_or_else(|| DepthMap::empty(vp.camera.width, vp.camera.height)))
        .collect();
    let filtered: Vec<DepthMap> = plan
        .views
        .iter()
        .enumerate()
        .map(|(view, vp)| {
            let neighbour_maps: Vec<Option<&DepthMap>> =
                vp.neighbours.iter().map(|&s| Some(&finals[s])).collect();
            filter_depth_map(&plan, view, &finals[view], &neighbour_maps, &options.filter)
        })
        .collect::<Result<_, _>>()?;
    let cloud = fuse(&plan, &options.fusion, &mut |view: usize| {
        let map = filtered[view].clone();
        Ok::<_, DenseError>(FusionView::new(map, &working[view]))
    })?;
    Ok(EpochResult {
        plan,
        depth_maps: finals,
        filtered,
        cloud,
    })
}

/// What [`reconstruct_epoch`] computes.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochResult {
    /// The plan.
    pub plan: EpochPlan,
    /// Each view's map after the last pass.
    pub depth_maps: Vec<DepthMap>,
    /// Each view's map after filtering.
    pub filtered: Vec<DepthMap>,
    /// The fused cloud.
    pub cloud: FusedCloud,
}

/// The colours of a working image at the size of a map (the image itself, or averaged down to
/// a coarser scale).
pub fn colours_at(image: &WorkingImage, width: usize, height: usize) -> Vec<[f32; 3]> {
    let mut rgb = image.rgb.clone();
    let (mut w, mut h) = (image.width(), image.height());
    while w > width && w / 2 >= width {
        let (hw, hh) = (w / 2, h / 2);
        let mut half = Vec::with_capacity(hw * hh);
        for j in 0..hh {
            for i in 0..hw {
                let mut c = [0.0f32; 3];
                for (di, dj) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let p = rgb[(2 * j + dj) * w + 2 * i + di];
                    for k in 0..3 {
                        c[k] += 0.25 * p[k];
                    }
                }
                half.push(c);
            }
        }
        rgb = half;
        w = hw;
        h = hh;
    }
    if w == width && h == height {
        rgb
    } else {
        vec![[0.0; 3]; width * height]
    }
}
