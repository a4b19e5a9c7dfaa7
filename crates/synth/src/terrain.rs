//! Heightfields: regular grids of heights triangulated into meshes (each cell split along its
//! (i, j)–(i+1, j+1) diagonal), with the exact height of that piecewise-planar surface anywhere,
//! so the truth DEMs written beside rendered images describe the very surface that was rendered.

use nalgebra::Vector3;

/// Heights on a regular grid of nodes; x grows with columns, y with rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Heightfield {
    /// World x, y of node (0, 0).
    pub origin: (f64, f64),
    /// Node spacing, metres.
    pub cell: f64,
    /// Nodes along x.
    pub nx: usize,
    /// Nodes along y.
    pub ny: usize,
    /// Heights, row-major (row = y index).
    pub z: Vec<f64>,
}

impl Heightfield {
    /// Samples `f(x, y)` at every node.
    pub fn from_fn(
        origin: (f64, f64),
        cell: f64,
        nx: usize,
        ny: usize,
        f: impl Fn(f64, f64) -> f64,
    ) -> Heightfield {
        let z = (0..nx * ny)
            .map(|k| {
                let (i, j) = (k % nx, k / nx);
                f(origin.0 + i as f64 * cell, origin.1 + j as f64 * cell)
            })
            .collect();
        Heightfield {
            origin,
            cell,
            nx,
            ny,
            z,
        }
    }

    /// Height of node (i, j).
    pub fn node(&self, i: usize, j: usize) -> f64 {
        self.z[j * self.nx + i]
    }

    /// Height of the triangulated surface at (x, y); `None` outside the grid.
    pub fn height_at(&self, x: f64, y: f64) -> Option<f64> {
        let fx = (x - self.origin.0) / self.cell;
        let fy = (y - self.origin.1) / self.cell;
        if !(fx >= 0.0 && fy >= 0.0 && fx <= (self.nx - 1) as f64 && fy <= (self.ny - 1) as f64) {
            return None;
        }
        let i = (fx.floor() as usize).min(self.nx - 2);
        let j = (fy.floor() as usize).min(self.ny - 2);
        let (u, v) = (fx - i as f64, fy - j as f64);
        let (z00, z10, z01, z11) = (
            self.node(i, j),
            self.node(i + 1, j),
            self.node(i, j + 1),
            self.node(i + 1, j + 1),
        );
        // Triangles (00, 10, 11) below the diagonal (u ≥ v) and (00, 11, 01) above it.
        Some(if u >= v {
            z00 + u * (z10 - z00) + v * (z11 - z10)
        } else {
            z00 + v * (z01 - z00) + u * (z11 - z01)
        })
    }

    /// The triangle mesh: vertices and triangles (two per cell, split as in [`Self::height_at`]).
    pub fn mesh(&self) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
        let vertices = (0..self.nx * self.ny)
            .map(|k| {
                let (i, j) = (k % self.nx, k / self.nx);
                Vector3::new(
                    self.origin.0 + i as f64 * self.cell,
                    self.origin.1 + j as f64 * self.cell,
                    self.z[k],
                )
            })
            .collect();
        let mut triangles = Vec::with_capacity(2 * (self.nx - 1) * (self.ny - 1));
        for j in 0..self.ny - 1 {
            for i in 0..self.nx - 1 {
                let k = |i: usize, j: usize| (j * self.nx + i) as u32;
                triangles.push([k(i, j), k(i + 1, j), k(i + 1, j + 1)]);
                triangles.push([k(i, j), k(i + 1, j + 1), k(i, j + 1)]);
            }
        }
        (vertices, triangles)
    }
}
