//! Filtering of a view's final depth map: a depth survives where at least `min_views`
//! neighbours (its sources and the views that have it as a source) agree with it (forward–backward reprojection through their maps within a pixel tolerance,
//! relative depth and normal tolerances), its matching cost is good, and it is not part of an
//! isolated speckle (a small connected region of similar depths). With `fill_edges`, a depth
//! that fewer than `min_views` neighbours can see at all (the block's edges) survives where
//! every neighbour that sees it agrees, and at least one does.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::DenseError;
use crate::camera::WorkingCamera;
use crate::depth_map::{DepthMap, NO_COST};
use crate::image::Mask;
use crate::plan::EpochPlan;

/// Options of the filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterOptions {
    /// Least number of neighbours that must agree with a depth.
    pub min_views: usize,
    /// Largest forward–backward reprojection error, pixels of the map.
    pub max_reprojection_px: f64,
    /// Largest relative depth difference.
    pub max_relative_depth: f64,
    /// Largest angle between the normals, degrees.
    pub max_normal_angle_deg: f64,
    /// Largest matching cost (1 − NCC, plus the geometric term of the last pass).
    pub max_cost: f32,
    /// Connected regions of fewer pixels are removed as speckles.
    pub min_region: usize,
    /// Where fewer than `min_views` neighbours have the point in their field at all (a
    /// block's edges, where ground is seen by two images), every one that has must agree
    /// instead (at least one). Occluded ground is in a neighbour's field: it keeps the
    /// strict count. Off by default: no third view then vets the depth.
    pub fill_edges: bool,
}

impl Default for FilterOptions {
    fn default() -> Self {
        FilterOptions {
            min_views: 2,
            max_reprojection_px: 2.0,
            max_relative_depth: 0.01,
            max_normal_angle_deg: 30.0,
            max_cost: 0.6,
            min_region: 10,
            fill_edges: false,
        }
    }
}

impl FilterOptions {
    /// Checks every option's domain.
    pub fn validate(&self) -> Result<(), DenseError> {
        if self.min_views == 0 {
            return Err(DenseError::InvalidOption(
                "min_views: expected at least 1".into(),
            ));
        }
        if !(self.max_reprojection_px > 0.0)
            || !(self.max_relative_depth > 0.0)
            || !(self.max_normal_angle_deg > 0.0)
            || !(self.max_cost > 0.0)
        {
            return Err(DenseError::InvalidOption(
                "filter tolerances must be positive".into(),
            ));
        }
        Ok(())
    }

    /// How many neighbours must agree with a depth that `seeing` of them have in their field.
    pub fn required_views(&self, seeing: usize) -> usize {
        if self.fill_edges {
            self.min_views.min(seeing).max(1)
        } else {
            self.min_views
        }
    }
}

/// A view's map as seen from another view: its camera at the map's scale and `other_from_ref`.
pub(crate) struct Neighbour<'a> {
    pub map: &'a DepthMap,
    pub camera: WorkingCamera,
    /// `other_from_ref` rotation.
    pub r: nalgebra::Matrix3<f64>,
    /// `other_from_ref` translation.
    pub t: Vector3<f64>,
    /// Which pixels of the map show the view's image.
    pub field: Field<'a>,
}

/// Which pixels of a neighbour's map show its image (a working image is larger than the
/// original where the lens has barrel distortion; user masks and no-data borders are out too).
pub(crate) enum Field<'a> {
    /// Those with a depth: a map before filtering has one at every usable pixel.
    Depth,
    /// Those its image's mask at the map's size keeps (filtered maps have holes); the caller
    /// checked that the mask has the map's size.
    Mask(&'a Mask),
}

/// The outcome of checking a reference depth against a neighbour's map.
pub(crate) struct Agreement {
    /// The neighbour's pixel index.
    pub pixel: usize,
    /// The neighbour's point, reference frame.
    pub point: Vector3<f64>,
    /// The neighbour's normal, reference frame.
    pub normal: Vector3<f64>,
    /// How much coarser the neighbour sees the surface there than the reference (≥ 1).
    pub coarser: f64,
}

/// Tolerances of the agreement between a depth and a neighbour's map.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tolerances {
    /// Largest forward–backward reprojection error, pixels.
    pub max_px: f64,
    /// Largest relative depth difference.
    pub max_rel: f64,
    /// Least cosine between the normals.
    pub min_cos: f64,
    /// Farthest a candidate pixel's centre may be from the projection of the reference point,
    /// neighbour pixels. Filtering takes any of the four nearest pixels (∞); fusion only those
    /// within a pixel, so that every image a fused point is made from saw it within a pixel of
    /// where it projects.
    pub max_centre_px: f64,
}

impl Neighbour<'_> {
    /// Whether the reference point `x` (reference frame) lies in front of the neighbour and
    /// projects onto a pixel of its map that shows its image: whether it could see it,
    /// occlusion aside.
    pub fn sees(&self, x: &Vector3<f64>) -> bool {
        let Some(p) = self.camera.project(&(self.r * x + self.t)) else {
            return false;
        };
        // The camera is the map's (same size), so a pixel it contains is one of the map's.
        if !self.camera.contains(p.x, p.y) {
            return false;
        }
        let (i, j) = (p.x as usize, p.y as usize);
        match self.field {
            Field::Depth => self.map.depth[j * self.map.width + i] > 0.0,
            Field::Mask(mask) => mask.at(i, j),
        }
    }

    /// Whether the neighbour's map agrees with the reference point `x` (reference frame) seen at
    /// reference pixel (u, v) with normal `n`: the neighbour's depth at one of the four pixels
    /// nearest to the projection of `x` (nearest first, skipping those `skip` refuses), lifted
    /// and projected back, lands within `max_px` pixels of the coarser of the two views of
    /// (u, v), its depth along the reference ray is within `max_rel` of the reference depth,
    /// and the normals agree.
    pub fn agrees(
        &self,
        ref_camera: &WorkingCamera,
        (u, v): (f64, f64),
        x: &Vector3<f64>,
        n: &Vector3<f64>,
        tolerances: &Tolerances,
        skip: &dyn Fn(usize) -> bool,
    ) -> Option<Agreement> {
        let xo = self.r * x + self.t;
        let p = self.camera.project(&xo)?;
        if !self.camera.contains(p.x, p.y) {
            return None;
        }
        // The pixel containing p first, then the other pixels of the 2 × 2 block of centres
        // around it, by distance.
        let (i0, j0) = (p.x as i64, p.y as i64);
        let (di, dj) = (
            if p.x - i0 as f64 >= 0.5 { 1 } else { -1 },
            if p.y - j0 as f64 >= 0.5 { 1 } else { -1 },
        );
        let (fx, fy) = ((p.x - i0 as f64 - 0.5).abs(), (p.y - j0 as f64 - 0.5).abs());
        let mut candidates = [(i0, j0), (i0 + di, j0), (i0, j0 + dj), (i0 + di, j0 + dj)];
        if fy > fx {
            candidates.swap(1, 2);
        }
        candidates.into_iter().find_map(|(i, j)| {
            if i < 0 || j < 0 || i >= self.map.width as i64 || j >= self.map.height as i64 {
                return None;
            }
            let k = j as usize * self.map.width + i as usize;
            if skip(k) {
                return None;
            }
            let (cu, cv) = (i as f64 + 0.5, j as f64 + 0.5);
            if (cu - p.x).powi(2) + (cv - p.y).powi(2) > tolerances.max_centre_px.powi(2) {
                return None;
            }
            self.check(ref_camera, (u, v), x, n, tolerances, (p.x, p.y), k)
        })
    }

    /// The check of [`Neighbour::agrees`] with the neighbour's pixel `k`, its depth lifted at
    /// the projection `(pu, pv)` itself (as ACMM's geometric cost does) rather than at the pixel's
    /// centre: a neighbour seeing the surface at a coarser scale would otherwise miss by a
    /// fraction of its own pixel, several of the reference's.
    #[allow(clippy::too_many_arguments)]
    fn check(
        &self,
        ref_camera: &WorkingCamera,
        (u, v): (f64, f64),
        x: &Vector3<f64>,
        n: &Vector3<f64>,
        tolerances: &Tolerances,
        (pu, pv): (f64, f64),
        k: usize,
    ) -> Option<Agreement> {
        let d = self.map.depth[k] as f64;
        if !(d > 0.0) {
            return None;
        }
        let yo = self.camera.ray(pu, pv) * d;
        let y = self.r.transpose() * (yo - self.t);
        let back = ref_camera.project(&y)?;
        // Pixels of the coarser of the two views: a neighbour that sees the surface from twice
        // as far places it to within its own pixel, two of the reference's.
        let coarser = ((yo.z / self.camera.f) / (x.z / ref_camera.f)).max(1.0);
        let max_px = tolerances.max_px * coarser;
        if (back.x - u).powi(2) + (back.y - v).powi(2) > max_px * max_px {
            return None;
        }
        if ((y.z - x.z) / x.z).abs() > tolerances.max_rel {
            return None;
        }
        let no = self.map.normal[k];
        let normal = self.r.transpose() * Vector3::new(no[0] as f64, no[1] as f64, no[2] as f64);
        if normal.dot(n) < tolerances.min_cos {
            return None;
        }
        Some(Agreement {
            pixel: k,
            point: y,
            normal,
            coarser,
        })
    }
}

/// The camera of a map of `width × height` made for a view of working camera `camera`.
pub(crate) fn camera_of_map(
    camera: &WorkingCamera,
    width: usize,
    height: usize,
) -> Option<WorkingCamera> {
    (0..16)
        .map(|s| camera.at_scale(s))
        .find(|c| c.width == width && c.height == height)
}

/// Neighbours of `view` from its neighbours' maps (`None` entries are skipped).
pub(crate) fn neighbours<'a>(
    plan: &EpochPlan,
    view: usize,
    maps: &[Option<&'a DepthMap>],
) -> Vec<Neighbour<'a>> {
    let vp = &plan.views[view];
    let local_from_ref = vp.cam_from_local.inverse();
    vp.neighbours
        .iter()
        .zip(maps)
        .filter_map(|(&s, m)| {
            let m = (*m)?;
            let sp = &plan.views[s];
            let camera = camera_of_map(&sp.camera, m.width, m.height)?;
            let other_from_ref = sp.cam_from_local * local_from_ref;
            Some(Neighbour {
                map: m,
                camera,
                r: other_from_ref.rotation_matrix(),
                t: other_from_ref.translation,
                field: Field::Depth,
            })
        })
        .collect()
}

/// The filtered map of `view`, checked against its neighbours' maps (`neighbour_maps` in the
/// order of [`crate::plan::ViewPlan::neighbours`]; a missing one counts as disagreeing).
pub fn filter_depth_map(
    plan: &EpochPlan,
    view: usize,
    map: &DepthMap,
    neighbour_maps: &[Option<&DepthMap>],
    options: &FilterOptions,
) -> Result<DepthMap, DenseError> {
    options.validate()?;
    let vp = plan
        .views
        .get(view)
        .ok_or_else(|| DenseError::InvalidInput(format!("no view {view} in the plan")))?;
    let camera = camera_of_map(&vp.camera, map.width, map.height).ok_or_else(|| {
        DenseError::InvalidInput(format!(
            "a depth map of {} × {} fits no scale of view {view}",
            map.width, map.height
        ))
    })?;
    if !map.is_consistent() {
        return Err(DenseError::InvalidInput(
            "a depth map's channels differ in length".into(),
        ));
    }
    let others = neighbours(plan, view, neighbour_maps);
    let tolerances = Tolerances {
        max_px: options.max_reprojection_px,
        max_centre_px: f64::INFINITY,
        max_rel: options.max_relative_depth,
        min_cos: options.max_normal_angle_deg.to_radians().cos(),
    };
    // Each pixel's agreement is its own, so rows are checked in parallel (the same result on
    // any number of threads); which pixels are kept is then copied in one pass.
    let width = map.width;
    let mut keep = vec![false; map.depth.len()];
    keep.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(j, row)| {
            for (i, kept) in row.iter_mut().enumerate() {
                let k = j * width + i;
                let d = map.depth[k];
                if !(d > 0.0) || !(map.cost[k] <= options.max_cost) {
                    continue;
                }
                let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
                let x = camera.ray(u, v) * d as f64;
                let nn = map.normal[k];
                let n = Vector3::new(nn[0] as f64, nn[1] as f64, nn[2] as f64);
                // A neighbour that agrees sees the point, whichever of its four nearest
                // pixels agreed.
                let (mut seeing, mut agreeing) = (0, 0);
                for o in &others {
                    if o.agrees(&camera, (u, v), &x, &n, &tolerances, &|_| false)
                        .is_some()
                    {
                        agreeing += 1;
                        seeing += 1;
                    } else if options.fill_edges && o.sees(&x) {
                        seeing += 1;
                    }
                }
                *kept = agreeing >= options.required_views(seeing);
            }
        });
    let mut out = DepthMap::empty(map.width, map.height);
    for k in (0..keep.len()).filter(|&k| keep[k]) {
        out.depth[k] = map.depth[k];
        out.normal[k] = map.normal[k];
        out.cost[k] = map.cost[k];
        out.upsampled[k] = map.upsampled[k];
    }
    remove_speckles(
        &mut out,
        &camera,
        options.min_region,
        options.max_relative_depth as f32,
    );
    Ok(out)
}

/// Removes connected regions of fewer than `min_region` pixels. Two 4-neighbours are connected
/// when the depth of one is within `max_rel` of the depth the other's plane predicts there: on
/// ground seen at a grazing angle, depth changes by more than that from pixel to pixel, and a
/// plain depth difference would cut a smooth surface into speckles. `camera` is the map's.
pub fn remove_speckles(
    map: &mut DepthMap,
    camera: &WorkingCamera,
    min_region: usize,
    max_rel: f32,
) {
    if min_region <= 1 {
        return;
    }
    let (w, h) = (map.width, map.height);
    let mut label = vec![u32::MAX; w * h];
    let mut stack = Vec::new();
    let mut members = Vec::new();
    let mut next = 0u32;
    for start in 0..w * h {
        if !(map.depth[start] > 0.0) || label[start] != u32::MAX {
            continue;
        }
        members.clear();
        stack.push(start);
        label[start] = next;
        while let Some(k) = stack.pop() {
            members.push(k);
            let (x, y) = (k % w, k / w);
            let d = map.depth[k] as f64;
            let n = map.normal[k].map(f64::from);
            let n = Vector3::new(n[0], n[1], n[2]);
            // The plane n·X = c through this pixel's point.
            let c = n.dot(&(camera.pixel_ray(x, y) * d));
            let mut visit = |q: usize| {
                let e = map.depth[q];
                if !(e > 0.0) || label[q] != u32::MAX {
                    return;
                }
                let ray = camera.pixel_ray(q % w, q / w);
                let denom = n.dot(&ray);
                let predicted = if denom.abs() > 1e-9 { c / denom } else { d };
                let predicted = if predicted > 0.0 { predicted } else { d };
                if (e as f64 - predicted).abs() <= max_rel as f64 * predicted {
                    label[q] = next;
                    stack.push(q);
                }
            };
            if x > 0 {
                visit(k - 1);
            }
            if x + 1 < w {
                visit(k + 1);
            }
            if y > 0 {
                visit(k - w);
            }
            if y + 1 < h {
                visit(k + w);
            }
        }
        if members.len() < min_region {
            for &k in &members {
                map.depth[k] = 0.0;
                map.normal[k] = [0.0; 3];
                map.cost[k] = NO_COST;
                map.upsampled[k] = false;
            }
        }
        next += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speckles_go_and_regions_stay() {
        let mut map = DepthMap::empty(10, 10);
        for j in 0..5 {
            for i in 0..5 {
                map.depth[j * 10 + i] = 10.0;
            }
        }
        map.depth[8 * 10 + 8] = 10.0;
        map.depth[8 * 10 + 9] = 10.02;
        let camera = WorkingCamera {
            width: 10,
            height: 10,
            f: 10.0,
            cx: 5.0,
            cy: 5.0,
        };
        for n in map.normal.iter_mut() {
            *n = [0.0, 0.0, -1.0];
        }
        remove_speckles(&mut map, &camera, 4, 0.01);
        assert_eq!(map.valid_count(), 25);
        assert_eq!(map.depth[88], 0.0);
    }
}
