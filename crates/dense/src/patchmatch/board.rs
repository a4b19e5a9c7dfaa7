//! The per-pixel hypotheses of one view, stored as two checkerboard halves so that a pass over
//! one colour reads only the other colour and writes only its own: the red–black scheme's
//! parallelism without data races, and results that do not depend on the thread count.

/// The hypothesis and bookkeeping of one pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelState {
    /// Unit plane normal, reference camera frame, facing the camera.
    pub n: [f32; 3],
    /// Plane offset: the plane is `n·X + w = 0`.
    pub w: f32,
    /// Depth of the plane at this pixel; 0 when the pixel has no hypothesis (masked).
    pub depth: f32,
    /// Matching cost of the hypothesis.
    pub cost: f32,
    /// Source views selected for this pixel (bit j for source j).
    pub views: u32,
    /// Cost of the upsampled hypothesis a hierarchy pass started from (the detail restorer's
    /// reference); unused elsewhere.
    pub start_cost: f32,
}

impl PixelState {
    /// A pixel without hypothesis.
    pub const NONE: PixelState = PixelState {
        n: [0.0, 0.0, -1.0],
        w: 0.0,
        depth: 0.0,
        cost: super::cost::WORST,
        views: 0,
        start_cost: super::cost::WORST,
    };
}

/// A colour of the checkerboard: pixel (x, y) is red where `x + y` is even, black where odd. A
/// half-pass updates one colour reading only the other.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Colour {
    /// `x + y` even.
    Red,
    /// `x + y` odd.
    Black,
}

impl Colour {
    /// Both, in the order a pass visits them.
    pub const BOTH: [Colour; 2] = [Colour::Red, Colour::Black];

    /// The index of its half in [`Board::cells`].
    #[inline]
    pub fn index(self) -> usize {
        match self {
            Colour::Red => 0,
            Colour::Black => 1,
        }
    }
}

/// Pixel states in checkerboard halves: colour `(x + y) % 2`, index `y * half_width + x / 2`.
pub struct Board {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Cells per row in each half.
    pub half_width: usize,
    /// The two colours.
    pub cells: [Vec<PixelState>; 2],
}

impl Board {
    /// A board of `width × height` pixels without hypotheses.
    pub fn new(width: usize, height: usize) -> Board {
        let half_width = width.div_ceil(2);
        Board {
            width,
            height,
            half_width,
            cells: [
                vec![PixelState::NONE; half_width * height],
                vec![PixelState::NONE; half_width * height],
            ],
        }
    }

    /// Colour and index of pixel (x, y).
    #[inline]
    pub fn slot(&self, x: usize, y: usize) -> (usize, usize) {
        ((x + y) & 1, y * self.half_width + x / 2)
    }

    /// The state of pixel (x, y).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> &PixelState {
        let (c, k) = self.slot(x, y);
        &self.cells[c][k]
    }

    /// The column of the `k`-th cell of row `y` in colour `colour` (may equal `width` for the
    /// last cell of a row of odd width: no pixel).
    #[inline]
    pub fn column(colour: Colour, y: usize, k: usize) -> usize {
        2 * k + ((colour.index() ^ y) & 1)
    }

    /// The cells of `colour`, to write, and the other colour's, to read.
    pub fn split(&mut self, colour: Colour) -> (&mut [PixelState], OtherHalf<'_>) {
        let (width, height, half_width) = (self.width, self.height, self.half_width);
        let [red, black] = &mut self.cells;
        let (mine, theirs) = match colour {
            Colour::Red => (red, &*black),
            Colour::Black => (black, &*red),
        };
        let other = OtherHalf {
            width,
            height,
            half_width,
            cells: theirs,
        };
        (mine, other)
    }
}

/// Read access to the other colour's cells during a half-pass.
pub struct OtherHalf<'a> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Cells per row.
    pub half_width: usize,
    /// The other colour's cells.
    pub cells: &'a [PixelState],
}

impl OtherHalf<'_> {
    /// The state at (x, y), which must be of the other colour; `None` outside the image.
    #[inline]
    pub fn get(&self, x: i64, y: i64) -> Option<&PixelState> {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return None;
        }
        Some(&self.cells[y as usize * self.half_width + x as usize / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_cover_every_pixel_once() {
        for (w, h) in [(5, 3), (4, 4), (1, 2)] {
            let b = Board::new(w, h);
            let mut seen = [vec![false; b.half_width * h], vec![false; b.half_width * h]];
            for y in 0..h {
                for x in 0..w {
                    let (c, k) = b.slot(x, y);
                    assert!(!seen[c][k]);
                    seen[c][k] = true;
                    let kk = k - y * b.half_width;
                    assert_eq!(Board::column(Colour::BOTH[c], y, kk), x);
                }
            }
        }
    }
}
