//! A depth map of one view: depth, normal and matching cost per pixel of its working camera (at
//! some pyramid scale).

/// Per pixel: depth along the optical axis (0 where there is none), the unit normal of the surface
/// in the view's camera frame (facing the camera), and the matching cost (1 − NCC, 0–2, plus the
/// geometric term in geometric passes).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Depth per pixel, metres; 0 where unknown.
    pub depth: Vec<f32>,
    /// Unit normal per pixel, camera frame; zero where the depth is unknown.
    pub normal: Vec<[f32; 3]>,
    /// Matching cost per pixel; 2 where the depth is unknown.
    pub cost: Vec<f32>,
    /// Per pixel, whether its plane was taken from the next coarser scale (upsampled) rather
    /// than matched at this map's resolution: a refinement pass matches again only where the
    /// coarser scale was poor. Such a pixel stands for a 2 × 2 block: fusion makes at most one
    /// point per block (the cloud keeps the coarser density where nothing was refined).
    pub upsampled: Vec<bool>,
}

/// Cost of a pixel without a depth (the worst NCC cost).
pub const NO_COST: f32 = 2.0;

impl DepthMap {
    /// A map without any depth.
    pub fn empty(width: usize, height: usize) -> DepthMap {
        DepthMap {
            width,
            height,
            depth: vec![0.0; width * height],
            normal: vec![[0.0; 3]; width * height],
            cost: vec![NO_COST; width * height],
            upsampled: vec![false; width * height],
        }
    }

    /// Pixels with a depth.
    pub fn valid_count(&self) -> usize {
        self.depth.iter().filter(|&&d| d > 0.0).count()
    }

    /// Checks that every channel has `width * height` values.
    pub fn is_consistent(&self) -> bool {
        let n = self.width * self.height;
        self.depth.len() == n
            && self.normal.len() == n
            && self.cost.len() == n
            && self.upsampled.len() == n
    }
}
