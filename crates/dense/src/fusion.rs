//! Fusion of the filtered depth maps of an epoch into one coloured cloud, in the manner of
//! COLMAP's stereo fusion: every pixel not yet used starts a point; the neighbours (sources, and
//! views that have this one as a source) whose depth at its projection agrees (reprojection, relative depth and normal tolerances) join it; a point
//! needs at least `min_images` images (never one) and becomes the mean of its members —
//! position, colour and normal — with the number of images. With `fill_edges`, a point that
//! fewer than `min_images` images can see at all (the reference and the neighbours that have it
//! in their field: a block's edges) needs every one of them, and still two. Every member pixel is used once.
//! Pixels whose plane a refinement kept from the coarser scale ([`DepthMap::upsampled`]) stand
//! for 2 × 2 blocks: a block that a point already stands for (one of its pixels started or
//! joined it) starts no other, so flat ground keeps the level's density.
//!
//! Views are visited in order and loaded through a caller's function, with a small cache, so
//! memory holds a reference view and its sources, not the block. The result does not depend on
//! the thread count: fusion itself is sequential (it is cheap next to PatchMatch).

use std::collections::VecDeque;

use nalgebra::{Matrix3, Vector3};

use crate::DenseError;
use crate::camera::WorkingCamera;
use crate::colours_at;
use crate::depth_map::DepthMap;
use crate::filter::{Field, Neighbour, Tolerances, camera_of_map, neighbours};
use crate::image::{Mask, WorkingImage};
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
    /// Where fewer than `min_images` images have the point in their field at all (a block's
    /// edges), a point needs all of them instead, and at least two. Off by default.
    pub fill_edges: bool,
}

impl FusionOptions {
    /// How many images a point must be made from that `seeing` images (the reference among
    /// them) have in their field.
    pub fn required_images(&self, seeing: usize) -> usize {
        if self.fill_edges {
            self.min_images.min(seeing).max(2)
        } else {
            self.min_images
        }
    }
}

impl Default for FusionOptions {
    fn default() -> Self {
        FusionOptions {
            min_images: 3,
            max_reprojection_px: 2.0,
            max_relative_depth: 0.01,
            max_normal_angle_deg: 30.0,
            fill_edges: false,
        }
    }
}

/// A neighbour's pixel may join several points when it sees the surface this much coarser than
/// the reference.
const SHARED_COARSER: f64 = 1.1;

/// What fusion reads of a view: its filtered map, the colours of its working image and which of
/// the map's pixels show the image.
#[derive(Debug, Clone, PartialEq)]
pub struct FusionView {
    /// The filtered depth map.
    pub map: DepthMap,
    /// Colour per pixel of the map, 0–1.
    pub rgb: Vec<[f32; 3]>,
    /// The working image's mask at the map's size: the pixels that show the image.
    pub field: Mask,
}

impl FusionView {
    /// The view of a filtered `map` made for the working `image`: its colours and mask
    /// averaged down to the map's size.
    pub fn new(map: DepthMap, image: &WorkingImage) -> FusionView {
        let rgb = colours_at(image, map.width, map.height);
        let field = mask_at(&image.mask, map.width, map.height);
        FusionView { map, rgb, field }
    }
}

/// `mask` halved to `width × height` (a pixel usable when all it covers are); every pixel
/// usable when no halving gives that size.
fn mask_at(mask: &Mask, width: usize, height: usize) -> Mask {
    let mut m = mask.clone();
    while m.width > width && m.width / 2 >= width {
        m = m.half();
    }
    if m.width == width && m.height == height {
        m
    } else {
        Mask::all(width, height)
    }
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
        let found = self.entries.iter().position(|(v, _)| *v == view);
        if let Some(entry) = found.and_then(|pos| self.entries.remove(pos)) {
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
    let mut claims = Claims {
        used: vec![Vec::new(); plan.views.len()],
        blocks: vec![Vec::new(); plan.views.len()],
    };
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
        let reference = reference_view(plan, view, &cache)?;
        for (v, o) in reference.other_view.iter().zip(&reference.others) {
            allocate_bits(&mut claims.used[*v], &mut claims.blocks[*v], o.map);
        }
        allocate_bits(
            &mut claims.used[view],
            &mut claims.blocks[view],
            reference.map,
        );
        let fusion = ViewFusion {
            plan,
            reference: &reference,
            tolerances: &tolerances,
            options,
        };
        let mut members = Vec::with_capacity(reference.others.len());
        for k in 0..reference.map.width * reference.map.height {
            if let Some(point) = fusion.point_at(k, &mut claims, &mut members) {
                point.push_to(&mut cloud);
            }
        }
    }
    Ok(cloud)
}

/// Which pixels of each view stand in a point already, and which 2 × 2 blocks of upsampled
/// pixels a point stands for, as bits (allocated the first time fusion meets a view).
struct Claims {
    used: Vec<Vec<u64>>,
    blocks: Vec<Vec<u64>>,
}

/// A reference view as fusion sees it: its map and colours, the camera of its map, and its
/// neighbours that have a map of a scale of their view, with their views and colours.
struct ReferenceView<'a> {
    view: usize,
    map: &'a DepthMap,
    rgb: &'a [[f32; 3]],
    camera: WorkingCamera,
    others: Vec<Neighbour<'a>>,
    /// View of each neighbour (neighbours skip maps of no scale of their view).
    other_view: Vec<usize>,
    other_rgb: Vec<&'a [[f32; 3]]>,
    /// The rotation and translation from the view's camera frame to the local frame.
    local_from_ref: (Matrix3<f64>, Vector3<f64>),
}

/// View `view` and its neighbours, all in `cache`; an error when its map and colours differ in
/// size or its map fits no scale of the view.
fn reference_view<'a>(
    plan: &EpochPlan,
    view: usize,
    cache: &'a Cache,
) -> Result<ReferenceView<'a>, DenseError> {
    let vp = &plan.views[view];
    // Invariant: `fuse` loaded the view and its neighbours just before, and the cache holds
    // 2 × (most neighbours + 1) views, so none of them was evicted.
    let loaded = |v: usize| cache.find(v).expect("just loaded");
    let reference = loaded(view);
    let map = &reference.map;
    if !map.is_consistent() || reference.rgb.len() != map.width * map.height {
        return Err(DenseError::InvalidInput(format!(
            "view {view}: depth map and colours differ in size"
        )));
    }
    let camera = camera_of_map(&vp.camera, map.width, map.height).ok_or_else(|| {
        DenseError::InvalidInput(format!(
            "view {view}: a depth map of {} × {} fits no scale of the view",
            map.width, map.height
        ))
    })?;
    let source_views: Vec<&FusionView> = vp.neighbours.iter().map(|&s| loaded(s)).collect();
    let maps: Vec<Option<&DepthMap>> = source_views.iter().map(|f| Some(&f.map)).collect();
    let mut others: Vec<Neighbour<'_>> = neighbours(plan, view, &maps);
    let other_view: Vec<usize> = vp
        .neighbours
        .iter()
        .zip(&source_views)
        .filter(|(s, f)| {
            camera_of_map(&plan.views[**s].camera, f.map.width, f.map.height).is_some()
        })
        .map(|(s, _)| *s)
        .collect();
    let other_rgb = other_view
        .iter()
        .map(|&v| loaded(v).rgb.as_slice())
        .collect();
    for (other, &v) in others.iter_mut().zip(&other_view) {
        let field = &loaded(v).field;
        if (field.width, field.height) != (other.map.width, other.map.height) {
            return Err(DenseError::InvalidInput(format!(
                "view {v}: depth map and field differ in size"
            )));
        }
        other.field = Field::Mask(field);
    }
    let world_from_ref = vp.cam_from_local.inverse();
    Ok(ReferenceView {
        local_from_ref: (world_from_ref.rotation_matrix(), world_from_ref.translation),
        view,
        map,
        rgb: &reference.rgb,
        camera,
        others,
        other_view,
        other_rgb,
    })
}

/// One reference view's fusion: a point per pixel not yet claimed that enough neighbours
/// agree with.
struct ViewFusion<'a> {
    plan: &'a EpochPlan,
    reference: &'a ReferenceView<'a>,
    tolerances: &'a Tolerances,
    options: &'a FusionOptions,
}

/// A fused point, world frame.
struct FusedPoint {
    position: Vector3<f64>,
    color: [f32; 3],
    normal: [f32; 3],
    images: u16,
    reprojection_px: f32,
}

impl FusedPoint {
    fn push_to(self, cloud: &mut FusedCloud) {
        cloud.positions.push(self.position);
        cloud.colors.push(self.color);
        cloud.normals.push(self.normal);
        cloud.images.push(self.images);
        cloud.reprojection_px.push(self.reprojection_px);
    }
}

impl ViewFusion<'_> {
    /// The point that pixel `k` of the reference starts, claiming its members' pixels; `None`
    /// where it has no depth, is claimed, or too few views agree. `members` is scratch.
    fn point_at(
        &self,
        k: usize,
        claims: &mut Claims,
        members: &mut Vec<(usize, usize)>,
    ) -> Option<FusedPoint> {
        let r = self.reference;
        let (map, view) = (r.map, r.view);
        let d = map.depth[k];
        if !(d > 0.0) || is_used(&claims.used[view], k) {
            return None;
        }
        // A plane upsampled from the coarser scale stands for its 2 × 2 block: a block that a
        // point already stands for (one of its pixels started or joined one) starts no other;
        // its pixels may still join points.
        let block = map.upsampled[k].then(|| block_of(map, k));
        if block.is_some_and(|b| is_used(&claims.blocks[view], b)) {
            return None;
        }
        set_used(&mut claims.used[view], k);
        let (i, j) = (k % map.width, k / map.width);
        let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
        let x = r.camera.ray(u, v) * d as f64;
        let nn = map.normal[k];
        let n = Vector3::new(nn[0] as f64, nn[1] as f64, nn[2] as f64);
        let mut sums = Sums {
            x,
            n,
            c: r.rgb[k].map(f64::from),
        };
        self.members(claims, (u, v), &x, &n, &mut sums, members);
        let count = members.len() + 1;
        if count < self.options.min_images {
            // Fewer only where no other image has the point in its field (`fill_edges`): the
            // reference, its members, and the other neighbours that see the point.
            let seeing = || {
                count
                    + (r.others.iter().enumerate())
                        .filter(|(o, other)| !members.iter().any(|m| m.0 == *o) && other.sees(&x))
                        .count()
            };
            if !self.options.fill_edges || count < self.options.required_images(seeing()) {
                return None;
            }
        }
        if let Some(b) = block {
            set_used(&mut claims.blocks[view], b);
        }
        for &(o, pixel) in members.iter() {
            set_used(&mut claims.used[r.other_view[o]], pixel);
            let map = r.others[o].map;
            if map.upsampled[pixel] {
                set_used(&mut claims.blocks[r.other_view[o]], block_of(map, pixel));
            }
        }
        Some(self.mean_point(members, (u, v), &n, &sums))
    }

    /// The neighbours' pixels that agree with the reference's point `x` (normal `n`) seen at
    /// (u, v), into `members` as (neighbour, pixel), their points, normals and colours added
    /// to `sums`.
    fn members(
        &self,
        claims: &Claims,
        (u, v): (f64, f64),
        x: &Vector3<f64>,
        n: &Vector3<f64>,
        sums: &mut Sums,
        members: &mut Vec<(usize, usize)>,
    ) {
        let r = self.reference;
        members.clear();
        for (o, other) in r.others.iter().enumerate() {
            let bits = &claims.used[r.other_view[o]];
            // A pixel of a view that sees the surface much coarser spans several of the
            // reference's: it may join each of their points (lifted where each projects), or
            // fusion would leave one point per coarse pixel.
            let Some(a) = other
                .agrees(&r.camera, (u, v), x, n, self.tolerances, &|k| {
                    is_used(bits, k)
                })
                .or_else(|| {
                    other
                        .agrees(&r.camera, (u, v), x, n, self.tolerances, &|_| false)
                        .filter(|a| a.coarser >= SHARED_COARSER)
                })
            else {
                continue;
            };
            members.push((o, a.pixel));
            sums.x += a.point;
            sums.n += a.normal;
            let c = r.other_rgb[o][a.pixel];
            for ch in 0..3 {
                sums.c[ch] += c[ch] as f64;
            }
        }
    }

    /// The mean of the reference's point and its members', in the world frame, with the
    /// largest distance of its projection from a member pixel's centre.
    fn mean_point(
        &self,
        members: &[(usize, usize)],
        (u, v): (f64, f64),
        n: &Vector3<f64>,
        sums: &Sums,
    ) -> FusedPoint {
        let r = self.reference;
        let count = members.len() + 1;
        let inv = 1.0 / count as f64;
        let mean_ref = sums.x * inv;
        let mut worst = r.camera.project(&mean_ref).map_or(f64::INFINITY, |p| {
            ((p.x - u).powi(2) + (p.y - v).powi(2)).sqrt()
        });
        for &(o, pixel) in members {
            let other = &r.others[o];
            let w = other.map.width;
            let (pu, pv) = ((pixel % w) as f64 + 0.5, (pixel / w) as f64 + 0.5);
            let e = other
                .camera
                .project(&(other.r * mean_ref + other.t))
                .map_or(f64::INFINITY, |p| {
                    ((p.x - pu).powi(2) + (p.y - pv).powi(2)).sqrt()
                });
            worst = worst.max(e);
        }
        let (rotation, translation) = r.local_from_ref;
        let mean_local = rotation * mean_ref + translation;
        let normal = (rotation * sums.n)
            .try_normalize(1e-12)
            .unwrap_or(rotation * n);
        FusedPoint {
            position: self.plan.world_from_local(&mean_local),
            color: sums.c.map(|c| (c * inv) as f32),
            normal: [normal.x as f32, normal.y as f32, normal.z as f32],
            images: count.min(u16::MAX as usize) as u16,
            reprojection_px: worst as f32,
        }
    }
}

/// Running sums of a point's members: positions and normals (reference frame), colours.
struct Sums {
    x: Vector3<f64>,
    n: Vector3<f64>,
    c: [f64; 3],
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
