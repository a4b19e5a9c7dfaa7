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

    /// The cell containing (x, y) and the position inside it (0–1 along x and y); `None` outside
    /// the grid.
    fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize, f64, f64)> {
        let fx = (x - self.origin.0) / self.cell;
        let fy = (y - self.origin.1) / self.cell;
        if !(fx >= 0.0 && fy >= 0.0 && fx <= (self.nx - 1) as f64 && fy <= (self.ny - 1) as f64) {
            return None;
        }
        let i = (fx.floor() as usize).min(self.nx - 2);
        let j = (fy.floor() as usize).min(self.ny - 2);
        Some((i, j, fx - i as f64, fy - j as f64))
    }

    /// Height of the triangulated surface at (x, y); `None` outside the grid.
    pub fn height_at(&self, x: f64, y: f64) -> Option<f64> {
        let (i, j, u, v) = self.cell_of(x, y)?;
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

    /// Bilinear interpolation of the node values at (x, y); `None` outside the grid.
    pub fn bilinear(&self, x: f64, y: f64) -> Option<f64> {
        let (i, j, u, v) = self.cell_of(x, y)?;
        let bottom = self.node(i, j) * (1.0 - u) + self.node(i + 1, j) * u;
        let top = self.node(i, j + 1) * (1.0 - u) + self.node(i + 1, j + 1) * u;
        Some(bottom * (1.0 - v) + top * v)
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

/// Cells per side of the tiles the ray walk visits first.
const TILE: usize = 8;

/// Ray casting against a [`Heightfield`]'s triangulated surface, exact on the same triangles as
/// [`Heightfield::mesh`]: a grid walk (Amanatides–Woo) over tiles of 8 × 8 cells skips those the
/// ray passes above (their highest node is below it), then walks the cells of the others the same
/// way, testing the two triangles of each cell the ray may touch as planes. Incremental walks
/// beat both a general BVH and a full maximum-pyramid descent on the million-triangle grids of
/// the scenes (measured).
#[derive(Debug, Clone)]
pub struct FieldTracer {
    field: Heightfield,
    /// Highest node of each cell.
    cells: MaxGrid,
    /// Highest node of each tile of TILE × TILE cells.
    tiles: MaxGrid,
    z_min: f64,
    z_max: f64,
}

/// The highest node height of each block of a regular partition of the grid.
#[derive(Debug, Clone)]
struct MaxGrid {
    width: usize,
    height: usize,
    /// Block side, metres.
    size: f64,
    max: Vec<f64>,
}

/// Where a ray meets a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldHit {
    /// Ray parameter (in units of the direction's length).
    pub t: f64,
    /// Unit normal of the triangle hit, pointing up (+z).
    pub normal: Vector3<f64>,
    /// Index of the triangle hit, in [`Heightfield::mesh`] order.
    pub triangle: usize,
}

/// Steps of a 2-D grid walk along a ray: the cell entered and the ray parameter there.
struct GridWalk {
    cell: (i64, i64),
    step: (i64, i64),
    t_next: (f64, f64),
    t_delta: (f64, f64),
}

impl GridWalk {
    /// The walk over cells of size `size` (grid origin at 0) of the ray `o + t d` from `t0`.
    fn new(o: (f64, f64), d: (f64, f64), t0: f64, size: f64) -> GridWalk {
        let p = (o.0 + t0 * d.0, o.1 + t0 * d.1);
        let cell = ((p.0 / size).floor() as i64, (p.1 / size).floor() as i64);
        let axis = |p: f64, d: f64, c: i64| -> (i64, f64, f64) {
            if d > 0.0 {
                (1, t0 + ((c + 1) as f64 * size - p) / d, size / d)
            } else if d < 0.0 {
                (-1, t0 + (c as f64 * size - p) / d, -size / d)
            } else {
                (0, f64::INFINITY, f64::INFINITY)
            }
        };
        let (sx, nx, dx) = axis(p.0, d.0, cell.0);
        let (sy, ny, dy) = axis(p.1, d.1, cell.1);
        GridWalk {
            cell,
            step: (sx, sy),
            t_next: (nx, ny),
            t_delta: (dx, dy),
        }
    }

    /// The parameter where the current cell is left; moves to the next cell.
    fn advance(&mut self) -> f64 {
        if self.t_next.0 < self.t_next.1 {
            let t = self.t_next.0;
            self.cell.0 += self.step.0;
            self.t_next.0 += self.t_delta.0;
            t
        } else {
            let t = self.t_next.1;
            self.cell.1 += self.step.1;
            self.t_next.1 += self.t_delta.1;
            t
        }
    }
}

impl FieldTracer {
    /// The tracer of a heightfield (at least 2 × 2 nodes).
    pub fn new(field: Heightfield) -> FieldTracer {
        let (cx, cy) = (field.nx - 1, field.ny - 1);
        let cells: Vec<f64> = (0..cx * cy)
            .map(|k| {
                let (i, j) = (k % cx, k / cx);
                field
                    .node(i, j)
                    .max(field.node(i + 1, j))
                    .max(field.node(i, j + 1))
                    .max(field.node(i + 1, j + 1))
            })
            .collect();
        let (tw, th) = (cx.div_ceil(TILE), cy.div_ceil(TILE));
        let mut tile_max = vec![f64::NEG_INFINITY; tw * th];
        for j in 0..cy {
            for i in 0..cx {
                let m = &mut tile_max[(j / TILE) * tw + i / TILE];
                *m = m.max(cells[j * cx + i]);
            }
        }
        let cells = MaxGrid {
            width: cx,
            height: cy,
            size: field.cell,
            max: cells,
        };
        let tiles = MaxGrid {
            width: tw,
            height: th,
            size: field.cell * TILE as f64,
            max: tile_max,
        };
        let z_min = field.z.iter().copied().fold(f64::INFINITY, f64::min);
        let z_max = field.z.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        FieldTracer {
            field,
            cells,
            tiles,
            z_min,
            z_max,
        }
    }

    /// The first hit of the ray `origin + t · dir`, t in (0, t_max].
    pub fn cast(&self, origin: &Vector3<f64>, dir: &Vector3<f64>, t_max: f64) -> Option<FieldHit> {
        let f = &self.field;
        // Grid-relative origin so that cell (i, j) spans [i, i+1) × [j, j+1) cells.
        let o = Vector3::new(origin.x - f.origin.0, origin.y - f.origin.1, origin.z);
        let (w, h) = ((f.nx - 1) as f64 * f.cell, (f.ny - 1) as f64 * f.cell);
        // Clip to the grid's box.
        let (mut t0, mut t1) = (0.0f64, t_max);
        for (o, d, lo, hi) in [
            (o.x, dir.x, 0.0, w),
            (o.y, dir.y, 0.0, h),
            (o.z, dir.z, self.z_min, self.z_max),
        ] {
            if d.abs() < 1e-300 {
                if o < lo || o > hi {
                    return None;
                }
            } else {
                let (a, b) = ((lo - o) / d, (hi - o) / d);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if t0 > t1 {
            return None;
        }
        // Walk the tiles in ray order, skipping those the ray passes above; walk the cells of
        // the others the same way, and test the triangles of the cells left.
        Self::walk(&o, dir, t0, t1, &self.tiles, |_, _, ta, tb| {
            Self::walk(&o, dir, ta, tb, &self.cells, |i, j, ta, tb| {
                self.cell_hit(&o, dir, i, j, ta, tb)
            })
        })
    }

    /// Walks the blocks of `grid` crossed by the ray (grid-relative origin `o`) for parameters
    /// in [t0, t1], in ray order, and returns the first hit `visit(i, j, ta, tb)` finds in a
    /// block the ray does not pass above.
    fn walk(
        o: &Vector3<f64>,
        dir: &Vector3<f64>,
        t0: f64,
        t1: f64,
        grid: &MaxGrid,
        mut visit: impl FnMut(usize, usize, f64, f64) -> Option<FieldHit>,
    ) -> Option<FieldHit> {
        let mut blocks = GridWalk::new((o.x, o.y), (dir.x, dir.y), t0, grid.size);
        let mut ta = t0;
        loop {
            let (i, j) = blocks.cell;
            let tb = blocks.advance().min(t1);
            if i >= 0 && j >= 0 && (i as usize) < grid.width && (j as usize) < grid.height {
                let (i, j) = (i as usize, j as usize);
                let lowest = (o.z + ta * dir.z).min(o.z + tb * dir.z);
                if lowest <= grid.max[j * grid.width + i] + 1e-9 {
                    if let Some(hit) = visit(i, j, ta, tb) {
                        return Some(hit);
                    }
                }
            }
            if tb >= t1 {
                return None;
            }
            ta = tb;
        }
    }

    /// The ray (grid-relative origin `o`) against the two triangles of cell (i, j), parameter
    /// within [ta, tb]: each triangle is the plane z = z00 + u·A + v·B over its half of the cell
    /// (u, v the cell coordinates), so a hit is one division and two comparisons.
    fn cell_hit(
        &self,
        o: &Vector3<f64>,
        dir: &Vector3<f64>,
        i: usize,
        j: usize,
        ta: f64,
        tb: f64,
    ) -> Option<FieldHit> {
        let f = &self.field;
        let (z00, z10, z01, z11) = (
            f.node(i, j),
            f.node(i + 1, j),
            f.node(i, j + 1),
            f.node(i + 1, j + 1),
        );
        let inv = 1.0 / f.cell;
        let (u0, v0) = (o.x * inv - i as f64, o.y * inv - j as f64);
        let (du, dv) = (dir.x * inv, dir.y * inv);
        let eps_t = 1e-9 * (1.0 + tb.abs());
        const EPS: f64 = 1e-9;
        let mut best: Option<(f64, usize, f64, f64)> = None;
        // Triangle 0 (u ≥ v): slopes A = z10 − z00 along u, B = z11 − z10 along v.
        // Triangle 1 (v ≥ u): A = z11 − z01, B = z01 − z00.
        for (k, a, b) in [(0, z10 - z00, z11 - z10), (1, z11 - z01, z01 - z00)] {
            let den = dir.z - du * a - dv * b;
            if den.abs() < 1e-300 {
                continue;
            }
            let t = (z00 + u0 * a + v0 * b - o.z) / den;
            if t < ta - eps_t || t > tb + eps_t || t <= 0.0 {
                continue;
            }
            let (u, v) = (u0 + t * du, v0 + t * dv);
            let inside = u >= -EPS
                && v >= -EPS
                && u <= 1.0 + EPS
                && v <= 1.0 + EPS
                && if k == 0 { u >= v - EPS } else { v >= u - EPS };
            if inside && best.is_none_or(|(bt, ..)| t < bt) {
                best = Some((t, k, a, b));
            }
        }
        best.map(|(t, k, a, b)| FieldHit {
            t,
            normal: Vector3::new(-a * inv, -b * inv, 1.0).normalize(),
            triangle: 2 * (j * (f.nx - 1) + i) + k,
        })
    }
}
