//! Schur elimination of the eliminated blocks (points, or poses) into the reduced camera system:
//! `S −= Σ_b Ê_b V_b⁻¹ Ê_bᵀ` and `rhs −= Σ_b Ê_b V_b⁻¹ g_b`, where `Ê_b` stacks block `b`'s coupling
//! rows by distinct reduced-side column.
//!
//! Why this shape: each product is a handful of flops scattered over `S`, so a scalar loop over
//! pairs of columns spends its time on indexing, and on small blocks elimination was most of a
//! bundle adjustment's time, on one core. Here each block's rows are merged by column, sorted by
//! it and cut into segments of consecutive columns of one observation (a pose, an intrinsics
//! group, a point) once per structure ([`BlockRows`], refilled with each linearisation's values),
//! stored segment by segment with the `D` components apart, so that a segment pair's products are
//! a short vector loop over rows.
//! Only `S`'s lower triangle — all that its Cholesky factorisation reads — is written, in bands of
//! whole columns, one task per band: tasks never write the same memory, and every entry receives
//! its blocks' products one per block in block order, each computed with the same operands and
//! operations as the serial observation-pair formulation this replaced. The result is the same bit
//! for bit whatever the number of threads or bands.

use std::ops::Range;

use nalgebra::{DVector, SMatrix, SVector};
use rayon::prelude::*;

use crate::reduced::{Reduced, SparsePattern};

/// Longest segment: the reduced-side columns of one observation (a pose, a point, intrinsics).
const SEGMENT_MAX: usize = 9 + timesift_core::camera::MAX_INTRINSICS;

/// Blocks per task when building or refilling [`BlockRows`]; any value gives the same result.
const BLOCKS_PER_CHUNK: usize = 1024;

/// Chunks built at once by [`BlockRows::new`] before they are joined: enough for the threads,
/// few enough that the parts in flight stay small beside the structure.
const CHUNKS_PER_BATCH: usize = 16;

/// The coupling rows of one linearisation: per observation its reduced-side columns and its rows
/// `E = w J_cᵀ J_e` (row-major, count × D), and the observations of each eliminated block.
pub(crate) struct Coupling<'a> {
    pub(crate) obs_cols: &'a [(usize, usize)],
    pub(crate) cols: &'a [usize],
    pub(crate) e: &'a [f64],
    pub(crate) point_obs: &'a [Vec<usize>],
}

/// Consecutive reduced-side columns of one block first met together in one observation.
#[derive(Clone, Copy)]
struct Segment {
    /// First column.
    col: usize,
    len: usize,
    /// First entry (merged column) of the segment in its block's storage; its rows occupy
    /// `D * entry .. D * (entry + len)` of the component-major arrays.
    entry: usize,
    /// Rank of its first column in the block's observation order.
    first_seen: u32,
    /// The observation (position in the block's list) its columns came from.
    obs: u32,
}

/// Every eliminated block's coupling rows merged by reduced-side column (summed in observation
/// order), sorted by column and cut into [`Segment`]s, with what picks, for each pair of columns,
/// the operands the observation-pair formulation used.
pub(crate) struct BlockRows<const D: usize> {
    /// Block `b`'s segments are `seg_start[b]..seg_start[b + 1]`, by ascending column.
    seg_start: Vec<usize>,
    segments: Vec<Segment>,
    /// Merged rows, segment by segment, component-major within a segment (`[k][row]`).
    e: Vec<f64>,
    /// Per block: no two of its observations share a column.
    distinct: Vec<bool>,
    /// Column bands `bands[k]..bands[k + 1]` of about equal work, written by one task each.
    bands: Vec<usize>,
    /// Block chunks `chunks[k]..chunks[k + 1]` for the per-entry products.
    chunks: Vec<usize>,
    /// Per raw coupling row (observation row), where it is summed into `e`: the offset of its
    /// first component and the stride between components (its segment's length); `u32::MAX` for
    /// rows of no block.
    raw_slot: Vec<(u32, u32)>,
    /// The observations' column ranges the structure was built for.
    obs_cols: Vec<(usize, usize)>,
    /// The blocks in the order their products are subtracted: by their first two columns (the
    /// lowest-numbered two cameras that see a point), so that consecutive blocks write the same
    /// parts of `S`. Why: each block scatters products over `S`'s columns, and in the order the
    /// points happen to have that is one cache miss per run of rows (scale bench, 1,600 images:
    /// the scatter was 60 % of the align stage's time while its arithmetic was 15 %).
    order: Vec<u32>,
}

/// One chunk of blocks as built by a task, before concatenation.
struct PartRows {
    seg_start: Vec<usize>,
    segments: Vec<Segment>,
    e: Vec<f64>,
    distinct: Vec<bool>,
    /// Per column, the lower-triangle products it owns in these blocks.
    work: Vec<(usize, u64)>,
    /// Per raw row of these blocks: the row, its first component's offset in `e`, its stride.
    raw_slot: Vec<(usize, usize, u32)>,
}

impl<const D: usize> BlockRows<D> {
    /// Merges, sorts and segments the blocks' rows of a system with `n` reduced-side columns;
    /// `tasks` is the number of column bands to cut (any value gives the same result).
    pub(crate) fn new(n: usize, coupling: &Coupling<'_>, tasks: usize) -> Self {
        // Capacities are upper bounds (a merged row per raw row at most): pages never written
        // cost no memory, and the vectors are trimmed at the end. Growing them by doubling
        // instead copied and held up to twice their size, and building every part before
        // joining them held the structure twice over (heaptrack, scale bench at 800 images:
        // the parts were the largest allocations of the align stage).
        let mut rows = BlockRows {
            seg_start: Vec::with_capacity(coupling.point_obs.len() + 1),
            segments: Vec::with_capacity(coupling.cols.len()),
            e: Vec::with_capacity(coupling.e.len()),
            distinct: Vec::with_capacity(coupling.point_obs.len()),
            bands: Vec::new(),
            chunks: Vec::with_capacity(coupling.point_obs.len().div_ceil(BLOCKS_PER_CHUNK) + 1),
            raw_slot: vec![(u32::MAX, 0); coupling.cols.len()],
            obs_cols: coupling.obs_cols.to_vec(),
            order: Vec::new(),
        };
        let mut work = vec![0u64; n];
        rows.chunks.push(0);
        // A batch of chunks is built in parallel, then joined in order before the next.
        for batch in coupling
            .point_obs
            .chunks(BLOCKS_PER_CHUNK * CHUNKS_PER_BATCH)
        {
            let parts: Vec<PartRows> = batch
                .par_chunks(BLOCKS_PER_CHUNK)
                .map(|blocks| Self::part(n, coupling, blocks))
                .collect();
            for part in parts {
                rows.join(part, &mut work);
            }
        }
        rows.segments.shrink_to_fit();
        rows.e.shrink_to_fit();
        rows.seg_start.push(rows.segments.len());
        rows.bands = bands_of_equal_work(&work, tasks.max(1));
        rows.order = rows.locality_order();
        rows
    }

    /// Appends one part's blocks (built by [`Self::part`]) and adds its work per column.
    fn join(&mut self, part: PartRows, work: &mut [u64]) {
        let (seg0, entry0) = (self.segments.len(), self.e.len() / D);
        self.seg_start.extend(
            part.seg_start[..part.seg_start.len() - 1]
                .iter()
                .map(|s| s + seg0),
        );
        self.segments.extend(part.segments.iter().map(|s| Segment {
            entry: s.entry + entry0,
            ..*s
        }));
        for &(raw, p0, stride) in &part.raw_slot {
            self.raw_slot[raw] = (u32::try_from(p0 + entry0 * D).unwrap_or(u32::MAX), stride);
        }
        self.e.extend_from_slice(&part.e);
        self.distinct.extend_from_slice(&part.distinct);
        for (c, w) in part.work {
            work[c] += w;
        }
        self.chunks.push(self.distinct.len());
    }

    /// See [`BlockRows::order`]; ties keep the blocks' own order, so the order is a function of
    /// the structure alone (the same bits on any number of threads).
    fn locality_order(&self) -> Vec<u32> {
        let key = |b: usize| {
            let segs = &self.segments[self.seg_start[b]..self.seg_start[b + 1]];
            let col = |k: usize| segs.get(k).map_or(usize::MAX, |s| s.col);
            (col(0), col(1))
        };
        let mut order: Vec<u32> = (0..self.distinct.len() as u32).collect();
        order.sort_by_key(|&b| key(b as usize));
        order
    }

    /// Sums a new linearisation's rows into this structure, which is kept when every observation
    /// still has the columns it had (a point that falls behind a camera has none); `false`, and
    /// the structure is to be rebuilt, otherwise. The sums are made in the same order as
    /// [`Self::new`] makes them.
    pub(crate) fn refill(&mut self, coupling: &Coupling<'_>) -> bool {
        if coupling.obs_cols != self.obs_cols.as_slice() || self.e.len() >= u32::MAX as usize {
            return false;
        }
        let mut tasks = Vec::with_capacity(self.chunks.len());
        let mut rest = self.e.as_mut_slice();
        let mut base = 0;
        for w in self.chunks.windows(2) {
            let end = self.segments[..self.seg_start[w[1]]]
                .last()
                .map_or(base, |s| (s.entry + s.len) * D);
            let (chunk, r) = rest.split_at_mut(end - base);
            tasks.push((w[0]..w[1], base, chunk));
            (rest, base) = (r, end);
        }
        let raw_slot = &self.raw_slot;
        tasks.into_par_iter().for_each(|(blocks, base, e)| {
            e.fill(0.0);
            for obs in &coupling.point_obs[blocks] {
                for &a in obs {
                    let (sa, ca) = coupling.obs_cols[a];
                    for raw in sa..sa + ca {
                        let (p0, stride) = raw_slot[raw];
                        let (p0, stride) = (p0 as usize - base, stride as usize);
                        for k in 0..D {
                            e[p0 + k * stride] += coupling.e[raw * D + k];
                        }
                    }
                }
            }
        });
        true
    }

    fn part(n: usize, coupling: &Coupling<'_>, blocks: &[Vec<usize>]) -> PartRows {
        let mut part = PartRows {
            seg_start: Vec::with_capacity(blocks.len() + 1),
            segments: Vec::new(),
            e: Vec::new(),
            distinct: Vec::with_capacity(blocks.len()),
            work: Vec::new(),
            raw_slot: Vec::new(),
        };
        let mut local = vec![u32::MAX; n];
        // (column, first seen, observation, merged row)
        let mut merged: Vec<(usize, u32, u32, [f64; D])> = Vec::new();
        // Per raw row of the block: the row and its merged entry before sorting; then per entry
        // before sorting, its (offset, stride) in `e`.
        let mut raw_local: Vec<(usize, u32)> = Vec::new();
        let mut slot_of_local: Vec<(usize, u32)> = Vec::new();
        let mut entries = 0;
        for obs in blocks {
            part.seg_start.push(part.segments.len());
            merged.clear();
            raw_local.clear();
            let mut raw = 0;
            for (ia, &a) in obs.iter().enumerate() {
                let (sa, ca) = coupling.obs_cols[a];
                raw += ca;
                for ra in 0..ca {
                    let col = coupling.cols[sa + ra];
                    if local[col] == u32::MAX {
                        local[col] = merged.len() as u32;
                        merged.push((col, merged.len() as u32, ia as u32, [0.0; D]));
                    }
                    raw_local.push((sa + ra, local[col]));
                    let row = &mut merged[local[col] as usize].3;
                    let e = &coupling.e[(sa + ra) * D..(sa + ra + 1) * D];
                    for c in 0..D {
                        row[c] += e[c];
                    }
                }
            }
            for m in &merged {
                local[m.0] = u32::MAX;
            }
            part.distinct.push(merged.len() == raw);
            merged.sort_unstable_by_key(|m| m.0);
            let len = merged.len();
            slot_of_local.clear();
            slot_of_local.resize(len, (0, 0));
            let mut i = 0;
            while i < len {
                // The segment: columns, first-seen ranks and observation all run on together.
                let mut j = i + 1;
                while j < len
                    && j - i < SEGMENT_MAX
                    && merged[j].0 == merged[j - 1].0 + 1
                    && merged[j].1 == merged[j - 1].1 + 1
                    && merged[j].2 == merged[i].2
                {
                    j += 1;
                }
                part.segments.push(Segment {
                    col: merged[i].0,
                    len: j - i,
                    entry: entries + i,
                    first_seen: merged[i].1,
                    obs: merged[i].2,
                });
                for (r, m) in merged[i..j].iter().enumerate() {
                    slot_of_local[m.1 as usize] = (part.e.len() + r, (j - i) as u32);
                }
                for k in 0..D {
                    part.e.extend(merged[i..j].iter().map(|m| m.3[k]));
                }
                i = j;
            }
            part.raw_slot.extend(raw_local.iter().map(|&(raw, l)| {
                let (p0, stride) = slot_of_local[l as usize];
                (raw, p0, stride)
            }));
            part.work.extend(
                merged
                    .iter()
                    .enumerate()
                    .map(|(i, m)| (m.0, (len - i) as u64)),
            );
            entries += len;
        }
        part.seg_start.push(part.segments.len());
        part
    }
}

/// Cuts `0..work.len()` into at most `tasks` contiguous bands of about equal total work.
fn bands_of_equal_work(work: &[u64], tasks: usize) -> Vec<usize> {
    let total: u64 = work.iter().sum();
    let mut bands = vec![0];
    let mut acc = 0u64;
    let mut next = 1;
    for (c, &w) in work.iter().enumerate() {
        acc += w;
        if next < tasks && acc * tasks as u64 >= total * next as u64 && c + 1 < work.len() {
            bands.push(c + 1);
            while next < tasks && acc * tasks as u64 >= total * next as u64 {
                next += 1;
            }
        }
    }
    bands.push(work.len());
    bands.dedup();
    bands
}

/// The damped inverses `(V_b + λ diag(V_b))⁻¹` of the blocks (diagonal clamped as the reduced side's
/// is); `None` when one is singular.
pub(crate) fn damped_inverses<const D: usize>(
    v: &[SMatrix<f64, D, D>],
    lambda: f64,
) -> Option<Vec<SMatrix<f64, D, D>>> {
    let clamp = |d: f64| d.clamp(1e-6, 1e32);
    v.par_iter()
        .map(|v| {
            let mut vd = *v;
            for c in 0..D {
                vd[(c, c)] += lambda * clamp(v[(c, c)]);
            }
            vd.try_inverse()
        })
        .collect()
}

/// Subtracts every block's `Ê V⁻¹ Êᵀ` from `s` (lower triangle; a dense `s` is then mirrored) and
/// `Ê V⁻¹ g` from `rhs`, given the blocks' damped inverses `v_inv` and gradients `g_p`.
pub(crate) fn eliminate<const D: usize>(
    rows: &BlockRows<D>,
    v_inv: &[SMatrix<f64, D, D>],
    g_p: &[SVector<f64, D>],
    s: &mut Reduced,
    rhs: &mut DVector<f64>,
) {
    let vg: Vec<SVector<f64, D>> = v_inv
        .par_iter()
        .zip(g_p.par_iter())
        .map(|(inv, g)| inv * g)
        .collect();
    let products = Products {
        rows,
        v_inv,
        vg: &vg,
    };
    let rhs = rhs.as_mut_slice();
    match s {
        Reduced::Dense(m) => {
            let n = m.nrows();
            let data = m.as_mut_slice();
            let mut rest = &mut *data;
            products.subtract_in_bands(rhs, |cols| {
                let (band, r) = std::mem::take(&mut rest).split_at_mut(cols.len() * n);
                rest = r;
                DenseBand {
                    n,
                    c0: cols.start,
                    data: band,
                }
            });
            // The upper triangle, for readers other than the factorisation.
            for c in 0..n {
                for r in c + 1..n {
                    data[c + r * n] = data[r + c * n];
                }
            }
        }
        Reduced::Sparse { pattern, values } => {
            let mut rest = values.as_mut_slice();
            products.subtract_in_bands(rhs, |cols| {
                let base = pattern.col_ptr[cols.start];
                let len = pattern.col_ptr[cols.end] - base;
                let (band, r) = std::mem::take(&mut rest).split_at_mut(len);
                rest = r;
                SparseBand {
                    pattern,
                    base,
                    values: band,
                }
            });
        }
    }
}

/// The lower triangle of `S` on a band of columns.
trait LowerBand {
    /// Subtracts `v` from rows `row0..row0 + v.len()` of column `col` (`row0 ≥ col`).
    fn subtract_run(&mut self, col: usize, row0: usize, v: &[f64]);
}

/// Dense column-major storage of columns `c0..` (`n` rows each).
struct DenseBand<'a> {
    n: usize,
    c0: usize,
    data: &'a mut [f64],
}

impl LowerBand for DenseBand<'_> {
    #[inline(always)]
    fn subtract_run(&mut self, col: usize, row0: usize, v: &[f64]) {
        let start = (col - self.c0) * self.n + row0;
        let out = &mut self.data[start..start + v.len()];
        for (o, v) in out.iter_mut().zip(v) {
            *o -= v;
        }
    }
}

/// Compressed-column lower triangle whose band's values start at `base`.
struct SparseBand<'a> {
    pattern: &'a SparsePattern,
    base: usize,
    values: &'a mut [f64],
}

impl LowerBand for SparseBand<'_> {
    /// The pattern holds every product's entry; rows absent from it would be skipped.
    #[inline]
    fn subtract_run(&mut self, col: usize, row0: usize, v: &[f64]) {
        let (lo, hi) = (self.pattern.col_ptr[col], self.pattern.col_ptr[col + 1]);
        let rows = &self.pattern.row_idx[lo..hi];
        // A run's rows are consecutive columns of one observation: one block, or consecutive
        // blocks all coupled to this column's (the observation couples them), whose rows then
        // follow each other in the column. Where the block index places the first row, the
        // rest follow (checked in debug builds).
        if let Some(k) = self.pattern.position_in_column(col, row0) {
            if k + v.len() <= rows.len() {
                debug_assert!(v.is_empty() || rows[k + v.len() - 1] == row0 + v.len() - 1);
                let start = lo + k - self.base;
                for (o, v) in self.values[start..start + v.len()].iter_mut().zip(v) {
                    *o -= v;
                }
                return;
            }
        }
        let mut k = rows.partition_point(|&r| r < row0);
        // The usual case: the run's rows are consecutive in the pattern too (a pose's six
        // columns, a group's intrinsics), so its values are, and the run is one slice.
        let end = k + v.len();
        if !v.is_empty()
            && end <= rows.len()
            && rows[k] == row0
            && rows[end - 1] == row0 + v.len() - 1
        {
            let start = lo + k - self.base;
            for (o, v) in self.values[start..start + v.len()].iter_mut().zip(v) {
                *o -= v;
            }
            return;
        }
        for (t, &v) in v.iter().enumerate() {
            let row = row0 + t;
            while k < rows.len() && rows[k] < row {
                k += 1;
            }
            if k < rows.len() && rows[k] == row {
                self.values[lo + k - self.base] -= v;
            }
        }
    }
}

/// What the bands read: the rows, and per block `V⁻¹` and `V⁻¹ g`.
struct Products<'a, const D: usize> {
    rows: &'a BlockRows<D>,
    v_inv: &'a [SMatrix<f64, D, D>],
    vg: &'a [SVector<f64, D>],
}

/// One block's merged rows `Ê` and `F = Ê V⁻¹`, both component-major by segment; `e0` is the
/// block's first entry.
struct BlockView<'a> {
    e: &'a [f64],
    f: &'a [f64],
    e0: usize,
}

impl BlockView<'_> {
    /// The sources of the rows' and the columns' operands: `(F, Ê)` or `(Ê, F)`.
    #[inline(always)]
    fn sources(&self, f_from_rows: bool) -> (&[f64], &[f64]) {
        if f_from_rows {
            (self.f, self.e)
        } else {
            (self.e, self.f)
        }
    }

    /// Segment `s`'s rows in `src` (`D` components of `s.len` values each).
    #[inline(always)]
    fn segment<'s, const D: usize>(&self, src: &'s [f64], s: &Segment) -> &'s [f64] {
        let start = (s.entry - self.e0) * D;
        &src[start..start + D * s.len]
    }

    /// Column `cl` of segment `s` in `src`.
    #[inline(always)]
    fn column<const D: usize>(&self, src: &[f64], s: &Segment, cl: usize) -> [f64; D] {
        let start = (s.entry - self.e0) * D + cl;
        std::array::from_fn(|k| src[start + k * s.len])
    }
}

/// A segment pair's work: whether `F` comes from the rows' segment, the rows' segment, the
/// columns' segment, and which of its columns (those inside the band).
type PairWork<'s> = (bool, &'s Segment, &'s Segment, Range<usize>);

impl<const D: usize> Products<'_, D> {
    /// Runs [`Self::subtract_band`] on every band of columns, one task each; `band_of` hands out
    /// the storage of consecutive bands, in order.
    fn subtract_in_bands<B: LowerBand + Send>(
        &self,
        rhs: &mut [f64],
        mut band_of: impl FnMut(Range<usize>) -> B,
    ) {
        let bands = &self.rows.bands;
        let mut tasks = Vec::with_capacity(bands.len());
        let mut rest = rhs;
        for w in bands.windows(2) {
            let (rhs, r) = std::mem::take(&mut rest).split_at_mut(w[1] - w[0]);
            rest = r;
            tasks.push((w[0]..w[1], band_of(w[0]..w[1]), rhs));
        }
        tasks.into_par_iter().for_each(|(cols, mut band, rhs)| {
            self.subtract_band(cols, &mut band, rhs);
        });
    }

    /// Every block's products on the lower-triangle columns `band_cols`, in block order.
    fn subtract_band(&self, band_cols: Range<usize>, band: &mut impl LowerBand, rhs: &mut [f64]) {
        let rows = self.rows;
        let (c0, c1) = (band_cols.start, band_cols.end);
        let mut f = Vec::new();
        for &b in &rows.order {
            let b = b as usize;
            let segs = &rows.segments[rows.seg_start[b]..rows.seg_start[b + 1]];
            let (Some(first), Some(last)) = (segs.first(), segs.last()) else {
                continue;
            };
            if last.col + last.len <= c0 || first.col >= c1 {
                continue;
            }
            // F = Ê V⁻¹ of the block, each entry summed in component order as the pairwise loop did.
            // Recomputed by every band the block reaches: cheaper than writing and reading back F
            // for all blocks (D² products per entry against D per entry pair).
            let e = &rows.e[first.entry * D..(last.entry + last.len) * D];
            let inv = &self.v_inv[b];
            f.clear();
            f.resize(e.len(), 0.0);
            for s in segs {
                let start = (s.entry - first.entry) * D;
                for r in 0..s.len {
                    for c in 0..D {
                        let mut acc = 0.0;
                        for k in 0..D {
                            acc += e[start + k * s.len + r] * inv[(k, c)];
                        }
                        f[start + c * s.len + r] = acc;
                    }
                }
            }
            let view = BlockView {
                e,
                f: &f,
                e0: first.entry,
            };
            let vg = &self.vg[b];
            let distinct = rows.distinct[b];
            let start = segs.partition_point(|s| s.col + s.len <= c0);
            for (bi, col_seg) in segs.iter().enumerate().skip(start) {
                if col_seg.col >= c1 {
                    break;
                }
                // The segment's columns inside the band.
                let lo = c0.saturating_sub(col_seg.col);
                let hi = (c1 - col_seg.col).min(col_seg.len);
                for cl in lo..hi {
                    let e = view.column::<D>(e, col_seg, cl);
                    let mut dot = 0.0;
                    for c in 0..D {
                        dot += e[c] * vg[c];
                    }
                    rhs[col_seg.col + cl - c0] -= dot;
                }
                Self::diagonal_segment(&view, distinct, col_seg, lo..hi, band);
                for row_seg in &segs[bi + 1..] {
                    // F from the earlier of two observations, and from the row's side within one
                    // observation of a block whose observations share no column (the pairwise
                    // loop).
                    let f_from_rows = (distinct && row_seg.obs == col_seg.obs)
                        || row_seg.first_seen < col_seg.first_seen;
                    let work = (f_from_rows, row_seg, col_seg, lo..hi);
                    match row_seg.len {
                        6 => Self::segment_pair::<6>(&view, work, band),
                        3 => Self::segment_pair::<3>(&view, work, band),
                        2 => Self::segment_pair::<2>(&view, work, band),
                        1 => Self::segment_pair::<1>(&view, work, band),
                        _ => Self::segment_pair_any(&view, work, band),
                    }
                }
            }
        }
    }

    /// The products of the `L` rows of segment `a` with some columns of segment `b`, which lies
    /// above it, with `L` known to the compiler so that the loop over rows is unrolled and
    /// vectorised. Each product is summed from zero in component order, as the pairwise loop did.
    #[inline(always)]
    fn segment_pair<const L: usize>(
        view: &BlockView<'_>,
        (f_from_rows, a, b, cols): PairWork<'_>,
        band: &mut impl LowerBand,
    ) {
        let (row_src, col_src) = view.sources(f_from_rows);
        let rows = view.segment::<D>(row_src, a);
        if rows.len() != D * L {
            return;
        }
        for cl in cols {
            let w = view.column::<D>(col_src, b, cl);
            let mut acc = [0.0f64; L];
            for (k, &w) in w.iter().enumerate() {
                let src = &rows[k * L..(k + 1) * L];
                for r in 0..L {
                    acc[r] += src[r] * w;
                }
            }
            band.subtract_run(b.col + cl, a.col, &acc);
        }
    }

    /// [`Self::segment_pair`] for any segment length.
    fn segment_pair_any(
        view: &BlockView<'_>,
        (f_from_rows, a, b, cols): PairWork<'_>,
        band: &mut impl LowerBand,
    ) {
        let (row_src, col_src) = view.sources(f_from_rows);
        let rows = view.segment::<D>(row_src, a);
        let mut acc = [0.0f64; SEGMENT_MAX];
        for cl in cols {
            let acc = &mut acc[..a.len];
            column_products(rows, a.len, 0, &view.column::<D>(col_src, b, cl), acc);
            band.subtract_run(b.col + cl, a.col, acc);
        }
    }

    /// The products of a segment with itself, on and below the diagonal, for columns `cols`:
    /// `F` from the row's side in a block whose observations share no column (the pairwise
    /// loop), from the column's otherwise (within a segment the first-met order is the column
    /// order, and the merged loop took F from the earlier-met column).
    fn diagonal_segment(
        view: &BlockView<'_>,
        distinct: bool,
        a: &Segment,
        cols: Range<usize>,
        band: &mut impl LowerBand,
    ) {
        let (row_src, col_src) = view.sources(distinct);
        let rows = view.segment::<D>(row_src, a);
        let mut acc = [0.0f64; SEGMENT_MAX];
        for cl in cols {
            let acc = &mut acc[..a.len - cl];
            column_products(rows, a.len, cl, &view.column::<D>(col_src, a, cl), acc);
            band.subtract_run(a.col + cl, a.col + cl, acc);
        }
    }
}

/// `out[r] = Σ_k rows[k · stride + r0 + r] · w[k]` over a segment's component-major rows, summed
/// from zero in component order (the pairwise loop's order).
fn column_products<const D: usize>(
    rows: &[f64],
    stride: usize,
    r0: usize,
    w: &[f64; D],
    out: &mut [f64],
) {
    out.fill(0.0);
    let len = out.len();
    for (k, &w) in w.iter().enumerate() {
        let src = &rows[k * stride + r0..k * stride + r0 + len];
        for (o, &x) in out.iter_mut().zip(src) {
            *o += x * w;
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, Matrix3, Vector3};
    use proptest::prelude::*;
    use proptest::test_runner::RngSeed;

    use super::*;

    /// A random elimination problem: `cameras` poses of 6 columns, then (when `shared`) 2 intrinsic
    /// columns every observation carries, as a camera group's; blocks see 2–7 distinct cameras.
    struct Case {
        n: usize,
        obs_cols: Vec<(usize, usize)>,
        cols: Vec<usize>,
        e: Vec<f64>,
        point_obs: Vec<Vec<usize>>,
        v_inv: Vec<Matrix3<f64>>,
        g_p: Vec<Vector3<f64>>,
    }

    impl Case {
        fn new(seed: u64, shared: bool) -> Case {
            let mut state = seed | 1;
            let mut next = move || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            let cameras = 5 + (next() * 20.0) as usize;
            let n = 6 * cameras + if shared { 2 } else { 0 };
            let mut case = Case {
                n,
                obs_cols: Vec::new(),
                cols: Vec::new(),
                e: Vec::new(),
                point_obs: Vec::new(),
                v_inv: Vec::new(),
                g_p: Vec::new(),
            };
            for _ in 0..40 + (next() * 60.0) as usize {
                let mut seen: Vec<usize> = Vec::new();
                let views = 2 + (next() * 6.0) as usize;
                while seen.len() < views.min(cameras) {
                    let c = (next() * cameras as f64) as usize % cameras;
                    if !seen.contains(&c) {
                        seen.push(c);
                    }
                }
                let mut obs = Vec::new();
                for &c in &seen {
                    let start = case.cols.len();
                    case.cols.extend(6 * c..6 * c + 6);
                    if shared {
                        case.cols.extend(6 * cameras..6 * cameras + 2);
                    }
                    let count = case.cols.len() - start;
                    case.e.extend((0..3 * count).map(|_| 2.0 * next() - 1.0));
                    obs.push(case.obs_cols.len());
                    case.obs_cols.push((start, count));
                }
                case.point_obs.push(obs);
                let a = Matrix3::from_fn(|_, _| next() - 0.5);
                case.v_inv
                    .push(a * a.transpose() + Matrix3::identity() * (0.5 + next()));
                case.g_p.push(Vector3::from_fn(|_, _| next() - 0.5));
            }
            case
        }

        fn coupling(&self) -> Coupling<'_> {
            Coupling {
                obs_cols: &self.obs_cols,
                cols: &self.cols,
                e: &self.e,
                point_obs: &self.point_obs,
            }
        }

        /// `Σ_b Ê_b V_b⁻¹ Ê_bᵀ` and `Σ_b Ê_b V_b⁻¹ g_b` by dense products, `Ê_b` summed by column.
        fn reference(&self) -> (DMatrix<f64>, DVector<f64>) {
            let mut s = DMatrix::zeros(self.n, self.n);
            let mut rhs = DVector::zeros(self.n);
            for (b, obs) in self.point_obs.iter().enumerate() {
                let mut e_hat = DMatrix::zeros(self.n, 3);
                for &a in obs {
                    let (sa, ca) = self.obs_cols[a];
                    for ra in 0..ca {
                        for k in 0..3 {
                            e_hat[(self.cols[sa + ra], k)] += self.e[(sa + ra) * 3 + k];
                        }
                    }
                }
                let inv = DMatrix::from_fn(3, 3, |r, c| self.v_inv[b][(r, c)]);
                let g = DVector::from_fn(3, |r, _| self.g_p[b][r]);
                s += &e_hat * &inv * e_hat.transpose();
                rhs += &e_hat * (&inv * g);
            }
            (s, rhs)
        }

        fn eliminate(&self, tasks: usize, mut s: Reduced) -> (Reduced, DVector<f64>) {
            let rows = BlockRows::<3>::new(self.n, &self.coupling(), tasks);
            let mut rhs = DVector::zeros(self.n);
            eliminate(&rows, &self.v_inv, &self.g_p, &mut s, &mut rhs);
            (s, rhs)
        }

        fn full_pattern(&self) -> Arc<SparsePattern> {
            let all: Vec<usize> = (0..self.n).collect();
            SparsePattern::new(self.n, &[all], true).expect("a full pattern factorises")
        }
    }

    use std::sync::Arc;

    fn lower(s: &Reduced, n: usize) -> Vec<u64> {
        (0..n)
            .flat_map(|c| (c..n).map(move |r| (r, c)))
            .map(|(r, c)| s.get(r, c).to_bits())
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig {
            cases: 64,
            rng_seed: RngSeed::Fixed(0x5c4e_2026),
            ..ProptestConfig::default()
        })]

        /// The eliminated system is `−Σ Ê V⁻¹ Êᵀ` (to rounding) and symmetric in dense storage,
        /// with blocks whose observations share columns (a camera group) or not.
        #[test]
        fn elimination_matches_dense_products(seed in any::<u64>(), shared in any::<bool>()) {
            let case = Case::new(seed, shared);
            let (s, rhs) = case.eliminate(2, Reduced::dense(case.n));
            let (s_ref, rhs_ref) = case.reference();
            let scale = s_ref.amax().max(1.0);
            for r in 0..case.n {
                prop_assert!((rhs[r] + rhs_ref[r]).abs() <= 1e-12 * scale);
                for c in 0..case.n {
                    prop_assert!((s.get(r, c) + s_ref[(r, c)]).abs() <= 1e-12 * scale,
                        "({r}, {c}): {} against {}", s.get(r, c), -s_ref[(r, c)]);
                    prop_assert_eq!(s.get(r, c).to_bits(), s.get(c, r).to_bits());
                }
            }
        }

        /// The bits do not depend on the number of bands, nor on the storage.
        #[test]
        fn bands_and_storages_give_the_same_bits(seed in any::<u64>(), shared in any::<bool>()) {
            let case = Case::new(seed, shared);
            let (one, rhs_one) = case.eliminate(1, Reduced::dense(case.n));
            for tasks in [2, 3, 7] {
                let (dense, rhs) = case.eliminate(tasks, Reduced::dense(case.n));
                prop_assert_eq!(lower(&one, case.n), lower(&dense, case.n));
                prop_assert_eq!(rhs_one.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    rhs.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
                let (sparse, _) = case.eliminate(tasks, Reduced::sparse(case.full_pattern()));
                prop_assert_eq!(lower(&one, case.n), lower(&sparse, case.n));
            }
        }

        /// Rows refilled with a new linearisation's values are those built afresh; a changed
        /// structure (an observation that lost its columns) is refused.
        #[test]
        fn refilled_rows_equal_rebuilt_rows(seed in any::<u64>(), shared in any::<bool>()) {
            let mut case = Case::new(seed, shared);
            let mut rows = BlockRows::<3>::new(case.n, &case.coupling(), 2);
            for (k, e) in case.e.iter_mut().enumerate() {
                *e = (*e * 1.7 + k as f64 * 1e-3).sin();
            }
            prop_assert!(rows.refill(&case.coupling()));
            let fresh = BlockRows::<3>::new(case.n, &case.coupling(), 2);
            prop_assert_eq!(rows.e.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                fresh.e.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
            case.obs_cols[0].1 = 0;
            prop_assert!(!rows.refill(&case.coupling()));
        }
    }
}
