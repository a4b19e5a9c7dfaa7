//! Fusion of the filtered depth maps of an epoch into one coloured cloud, in the manner of
//! COLMAP's stereo fusion: every pixel not yet used starts a point; the neighbours (sources, and
//! views that have this one as a source) whose depth at its projection agrees (reprojection, relative depth and normal tolerances) join it; a point
//! needs at least `min_images` images (never one) and becomes the mean of its members —
//! position, colour and normal — with the number of images. Every member pixel is used once.
//! Pixels whose plane a refinement kept from the coarser scale ([`DepthMap::upsampled`]) stand
//! for 2 × 2 blocks: a block that a point already stands for (one of its pixels started or
//! joined it) starts no other, so flat ground keeps the level's density.
//!
//! Views are visited in order and loaded through a caller's function, with a small cache, so
//! memory holds a reference view and its sources, not the block. The result does not depend on
//! the thread count: fusion itself is sequential (it is cheap next to PatchMatch).

use std::collections::VecDeque;

use nalgebra::Vector3;

use crate::DenseError;
use crate::depth_map::DepthMap;
use crate::filter::{Neighbour, Tolerances, camera_of_map, neighbours};
use crate::plan::EpochPlan;

/// Options of the fusion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionOptions {
    /// Least images per fused point (3: no point from a single image or a single pair).
    pub min_images: usize,
    /// Largest forward–backward reprojection error, pixels of the maps.
    pub max_reprojection_px: f64,
    /// Largest relative depth difference.
    pub max_relative_depth: f64,
    /// Largest angle between the normals, degrees.
    pub max_normal_angle_deg: f64,
}

impl Default for FusionOptions {
    fn default() -> Self {
        FusionOptions {
            min_images: 3,
            max_reprojection_px: 2.0,
            max_relative_depth: 0.01,
            max_normal_angle_deg: 30.0,
        }
    }
}

/// A neighbour's pixel may join several points when it sees the surface this much coarser than
/// the reference.
const SHARED_COARSER: f64 = 1.1;

/// What fusion reads of a view: its filtered map and the colours of its working image.
#[derive(Debug, Clone, PartialEq)]
pub struct FusionView {
    /// The filtered depth map.
    pub map: DepthMap,
    /// Colour per pixel of the map, 0–1.
    pub rgb: Vec<[f32; 3]>,
}

/// The fused cloud of an epoch, world coordinates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FusedCloud {
    /// Positions, world frame (the input's CRS).
    pub positions: Vec<Vector3<f64>>,
    /// Colours, 0–1.
    pub colors: Vec<[f32; 3]>,
    /// Unit normals, world frame.
    pub normals: Vec<[f32; 3]>,
    /// Number of images each point was fused from.
    pub images: Vec<u16>,
    /// Per point, the largest distance between the projection of the fused position into a
    /// member view and the member pixel's centre, pixels of the maps.
    pub reprojection_px: Vec<f32>,
}

impl FusedCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    /// Whether the cloud is empty.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// Cache of loaded views, least recently used first out.
struct Cache {
    capacity: usize,
    entries: VecDeque<(usize, FusionView)>,
}

impl Cache {
    fn get<E>(
        &mut self,
        view: usize,
        load: &mut dyn FnMut(usize) -> Result<FusionView, E>,
    ) -> Result<(), E> {
        if let Some(pos) = self.entries.iter().position(|(v, _)| *v == view) {
            let entry = self.entries.remove(pos).expect("position is in range");
            self.entries.push_back(entry);
            return Ok(());
        }
        let loaded = load(view)?;
        if self.entries.len() >= self.capacity {
            self.entries.pop_front();
        }
        self.entries.push_back((view, loaded));
        Ok(())
    }

    fn find(&self, view: usize) -> Option<&FusionView> {
        self.entries
            .iter()
            .find(|(v, _)| *v == view)
            .map(|(_, f)| f)
    }
}

/// Fuses the views of `plan`, loading each through `load` (view index → its filtered map and
/// colours). Errors of `load` are returned as they are; inconsistent maps are
/// [`DenseError`]s converted through `E: From<DenseError>`.
pub fn fuse<E: From<DenseError>>(
    plan: &EpochPlan,
    options: &FusionOptions,
    load: &mut dyn FnMut(usize) -> Result<FusionView, E>,
) -> Result<FusedCloud, E> {
    if options.min_images < 2 {
        return Err(DenseError::InvalidOption(
            "fusion min_images: expected at least 2 (no point from a single image)".into(),
        )
        .into());
    }
    let max_neighbours = plan
        .views
        .iter()
        .map(|v| v.neighbours.len())
        .max()
        .unwrap_or(0);
    let mut cache = Cache {
        capacity: 2 * (max_neighbours + 1),
        entries: VecDeque::new(),
    };
    // Used pixels per view, as bits.
    let mut used: Vec<Vec<u64>> = vec![Vec::new(); plan.views.len()];
    // Per view, the 2 × 2 blocks of upsampled pixels that a point already stands for, as bits.
    let mut blocks: Vec<Vec<u64>> = vec![Vec::new(); plan.views.len()];
    let mut cloud = FusedCloud::default();
    let tolerances = Tolerances {
        max_px: options.max_reprojection_px,
        // A member pixel's centre within a pixel of where the point projects: the depth lifted
        // at the exact projection must not stand for a pixel that saw the surface elsewhere.
        max_centre_px: 1.0,
        max_rel: options.max_relative_depth,
        min_cos: options.max_normal_angle_deg.to_radians().cos(),
    };
    for view in 0..plan.views.len() {
        let vp = &plan.views[view];
        if vp.sources.is_empty() {
            continue;
        }
        for s in std::iter::once(view).chain(vp.neighbours.iter().copied()) {
            cache.get(s, load)?;
        }
        let reference = cache.find(view).expect("just loaded");
        let map = &reference.map;
        if !map.is_consistent() || reference.rgb.len() != map.width * map.height {
            return Err(DenseError::InvalidInput(format!(
                "view {view}: depth map and colours differ in size"
            ))
            .into());
        }
        let camera = camera_of_map(&vp.camera, map.width, map.height).ok_or_else(|| {
            DenseError::InvalidInput(format!(
                "view {view}: a depth map of {} × {} fits no scale of the view",
                map.width, map.height
            ))
        })?;
        let source_views: Vec<&FusionView> = vp
            .neighbours
            .iter()
            .map(|&s| cache.find(s).expect("just loaded"))
            .collect();
        let maps: Vec<Option<&DepthMap>> = source_views.iter().map(|f| Some(&f.map)).collect();
        let others: Vec<Neighbour<'_>> = neighbours(plan, view, &maps);
        // View of each neighbour (neighbours skip maps of no scale of their view).
        let other_view: Vec<usize> = vp
            .neighbours
            .iter()
            .zip(&source_views)
            .filter(|(s, f)| {
                camera_of_map(&plan.views[**s].camera, f.map.width, f.map.height).is_some()
            })
            .map(|(s, _)| *s)
            .collect();
        let other_rgb: Vec<&[[f32; 3]]> = other_view
            .iter()
            .map(|&v| cache.find(v).expect("just loaded").rgb.as_slice())
            .collect();
        for (v, o) in other_view.iter().zip(&others) {
            allocate_bits(&mut used[*v], &mut blocks[*v], o.map);
        }
        allocate_bits(&mut used[view], &mut blocks[view], map);
        let world_from_ref = vp.cam_from_local.inverse();
        let rotation = world_from_ref.rotation_matrix();
        let mut members: Vec<(usize, usize)> = Vec::with_capacity(others.len());
        for j in 0..map.height {
            for i in 0..map.width {
                let k = j * map.width + i;
                let d = map.depth[k];
                if !(d > 0.0) || is_used(&used[view], k) {
                    continue;
                }
                // A plane upsampled from the coarser scale stands for its 2 × 2 block: a block
                // that a point already stands for (one of its pixels started or joined one)
                // starts no other; its pixels may still join points.
                let block = map.upsampled[k].then(|| block_of(map, k));
                if block.is_some_and(|b| is_used(&blocks[view], b)) {
                    continue;
                }
                set_used(&mut used[view], k);
                let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
                let x = camera.ray(u, v) * d as f64;
                let nn = map.normal[k];
                let n = Vector3::new(nn[0] as f64, nn[1] as f64, nn[2] as f64);
                members.clear();
                let mut sum_x = x;
                let mut sum_n = n;
                let mut sum_c = reference.rgb[k].map(f64::from);
                for (o, other) in others.iter().enumerate() {
                    let bits = &used[other_view[o]];
                    // A pixel of a view that sees the surface much coarser spans several of the
                    // reference's: it may join each of their points (lifted where each projects),
                    // or fusion would leave one point per coarse pixel.
                    let Some(a) = other
                        .agrees(&camera, (u, v), &x, &n, &tolerances, &|k| is_used(bits, k))
                        .or_else(|| {
                            other
                                .agrees(&camera, (u, v), &x, &n, &tolerances, &|_| false)
                                .filter(|a| a.coarser >= SHARED_COARSER)
                        })
                    else {
                        continue;
                    };
                    members.push((o, a.pixel));
                    sum_x += a.point;
                    sum_n += a.normal;
                    let c = other_rgb[o][a.pixel];
                    for ch in 0..3 {
                        sum_c[ch] += c[ch] as f64;
                    }
                }
                let count = members.len() + 1;
                if count < options.min_images {
                    continue;
                }
                if let Some(b) = block {
                    set_used(&mut blocks[view], b);
                }
                for &(o, pixel) in &members {
                    set_used(&mut used[other_view[o]], pixel);
                    let map = others[o].map;
                    if map.upsampled[pixel] {
                        set_used(&mut blocks[other_view[o]], block_of(map, pixel));
                    }
                }
                let inv = 1.0 / count as f64;
                let mean_ref = sum_x * inv;
                let mut worst = camera.project(&mean_ref).map_or(f64::INFINITY, |p| {
                    ((p.x - u).powi(2) + (p.y - v).powi(2)).sqrt()
                });
                for &(o, pixel) in &members {
                    let other = &others[o];
                    let (w, _) = (other.map.width, other.map.height);
                    let (pu, pv) = ((pixel % w) as f64 + 0.5, (pixel / w) as f64 + 0.5);
                    let e = other
                        .camera
                        .project(&(other.r * mean_ref + other.t))
                        .map_or(f64::INFINITY, |p| {
                            ((p.x - pu).powi(2) + (p.y - pv).powi(2)).sqrt()
                        });
                    worst = worst.max(e);
                }
                let mean_local = rotation * mean_ref + world_from_ref.translation;
                let normal = (rotation * sum_n)
                    .try_normalize(1e-12)
                    .unwrap_or(rotation * n);
                cloud.positions.push(plan.world_from_local(&mean_local));
                cloud.colors.push(sum_c.map(|c| (c * inv) as f32));
                cloud
                    .normals
                    .push([normal.x as f32, normal.y as f32, normal.z as f32]);
                cloud.images.push(count.min(u16::MAX as usize) as u16);
                cloud.reprojection_px.push(worst as f32);
            }
        }
    }
    Ok(cloud)
}

#[inline]
fn is_used(bits: &[u64], k: usize) -> bool {
    bits[k / 64] >> (k % 64) & 1 == 1
}

/// A view's used-pixel and claimed-block bits, allocated the first time fusion meets it.
fn allocate_bits(used: &mut Vec<u64>, blocks: &mut Vec<u64>, map: &DepthMap) {
    if used.is_empty() {
        *used = vec![0; (map.width * map.height).div_ceil(64)];
        // The last row and column of an odd size are blocks too.
        *blocks = vec![0; (map.width.div_ceil(2) * map.height.div_ceil(2)).div_ceil(64)];
    }
}

/// The 2 × 2 block of pixel `k` of a map.
fn block_of(map: &DepthMap, k: usize) -> usize {
    let (x, y) = (k % map.width, k / map.width);
    (y / 2) * map.width.div_ceil(2) + x / 2
}

#[inline]
fn set_used(bits: &mut [u64], k: usize) {
    bits[k / 64] |= 1 << (k % 64);
}
