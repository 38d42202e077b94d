//! A piecewise-constant distribution over a grid of cells (rows × columns of
//! non-negative weights): a row by its marginal probability, then a column within it.
//!
//! Only the cumulative sums are stored (4 bytes per cell). A cell's probability is
//! the difference of two neighbouring sums — both in sampling and in [`Grid::pmf`] — so
//! the probability a sample reports is exactly the one it was drawn with, whatever the
//! sums' rounding: a cell whose difference rounds to zero is never drawn and reports
//! zero, which the integrator's MIS covers by BSDF sampling.

use glam::Vec2;

use crate::sampler::ONE_MINUS_EPSILON;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Grid {
    rows: u32,
    cols: u32,
    /// The rows' cumulative probabilities; the last row with weight ends at exactly 1.
    row_cdf: Vec<f32>,
    /// Per row, the columns' cumulative conditional probabilities (ending at 1).
    cdf: Vec<f32>,
}

/// A cell drawn from a [`Grid`]: where, where within it (uniform in `[0, 1)²`, x along
/// the row), and its probability.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridSample {
    pub row: u32,
    pub col: u32,
    pub offset: Vec2,
    pub pmf: f32,
}

/// Cumulative sums of `w`, normalised so that the last nonzero entry ends at exactly 1;
/// all zeros when the sum is not positive and finite.
fn cumulative(w: &[f64]) -> Vec<f32> {
    let total: f64 = w.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return vec![0.0; w.len()];
    }
    let mut acc = 0.0f64;
    let mut out: Vec<f32> = w
        .iter()
        .map(|&x| {
            acc += x;
            (acc / total) as f32
        })
        .collect();
    if let Some(last) = w.iter().rposition(|&x| x > 0.0) {
        out[last..].fill(1.0);
    }
    out
}

/// The index whose interval `[cdf[i-1], cdf[i])` holds `u`, that interval's width, and `u`
/// rescaled within it to `[0, 1)`.
#[inline]
fn find(cdf: &[f32], u: f32) -> (usize, f32, f32) {
    let i = cdf.partition_point(|&c| c <= u).min(cdf.len() - 1);
    let below = if i == 0 { 0.0 } else { cdf[i - 1] };
    let p = cdf[i] - below;
    let t = if p > 0.0 { ((u - below) / p).clamp(0.0, ONE_MINUS_EPSILON) } else { 0.0 };
    (i, p, t)
}

#[inline]
fn width(cdf: &[f32], i: usize) -> f32 {
    cdf[i] - if i == 0 { 0.0 } else { cdf[i - 1] }
}

impl Grid {
    /// The distribution of `weight(row, col)` over `rows × cols` cells (weights that are
    /// negative or not finite count as zero).
    pub fn new(rows: u32, cols: u32, weight: impl Fn(u32, u32) -> f64) -> Self {
        let clean = |x: f64| if x.is_finite() { x.max(0.0) } else { 0.0 };
        let mut cdf = Vec::with_capacity(rows as usize * cols as usize);
        let mut row_weight = Vec::with_capacity(rows as usize);
        let mut w = vec![0.0f64; cols as usize];
        for r in 0..rows {
            for (c, x) in w.iter_mut().enumerate() {
                *x = clean(weight(r, c as u32));
            }
            row_weight.push(w.iter().sum::<f64>());
            cdf.extend(cumulative(&w));
        }
        Self { rows, cols, row_cdf: cumulative(&row_weight), cdf }
    }

    /// Whether some cell has weight.
    pub fn is_empty(&self) -> bool {
        self.row_cdf.last().is_none_or(|&c| c <= 0.0)
    }

    fn row(&self, r: usize) -> &[f32] {
        &self.cdf[r * self.cols as usize..(r + 1) * self.cols as usize]
    }

    /// A cell with probability proportional to its weight; `None` if no cell has weight.
    #[inline]
    pub fn sample(&self, u: Vec2) -> Option<GridSample> {
        if self.is_empty() {
            return None;
        }
        let (r, p_row, ty) = find(&self.row_cdf, u.x);
        let (c, p_col, tx) = find(self.row(r), u.y);
        let pmf = p_row * p_col;
        (pmf > 0.0).then_some(GridSample { row: r as u32, col: c as u32, offset: Vec2::new(tx, ty), pmf })
    }

    /// The probability that [`Grid::sample`] draws cell (`row`, `col`).
    #[inline]
    pub fn pmf(&self, row: u32, col: u32) -> f32 {
        if row >= self.rows || col >= self.cols {
            return 0.0;
        }
        width(&self.row_cdf, row as usize) * width(self.row(row as usize), col as usize)
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.row_cdf.len() + self.cdf.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_drawn_in_proportion_to_their_weights() {
        let weights = [[1.0, 0.0, 3.0], [0.0, 0.0, 0.0], [2.0, 2.0, 0.0]];
        let grid = Grid::new(3, 3, |r, c| weights[r as usize][c as usize]);
        let n = 300;
        let mut counts = [[0u32; 3]; 3];
        for i in 0..n {
            for j in 0..n {
                let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                let s = grid.sample(u).unwrap();
                assert_eq!(s.pmf, grid.pmf(s.row, s.col));
                assert!(s.offset.cmpge(Vec2::ZERO).all() && s.offset.cmplt(Vec2::ONE).all());
                counts[s.row as usize][s.col as usize] += 1;
            }
        }
        for r in 0..3 {
            for c in 0..3 {
                let expect = weights[r][c] / 8.0;
                let got = f64::from(counts[r][c]) / f64::from(n * n);
                assert!((got - expect).abs() < 2e-3, "cell ({r}, {c}): {got} against {expect}");
                assert!((f64::from(grid.pmf(r as u32, c as u32)) - expect).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn offsets_are_uniform_within_the_cell() {
        // One cell: the offsets are the sample itself.
        let grid = Grid::new(1, 1, |_, _| 5.0);
        let s = grid.sample(Vec2::new(0.25, 0.75)).unwrap();
        assert_eq!((s.offset, s.pmf), (Vec2::new(0.75, 0.25), 1.0));
    }

    #[test]
    fn an_empty_grid_draws_nothing() {
        let grid = Grid::new(2, 2, |_, _| 0.0);
        assert!(grid.is_empty() && grid.sample(Vec2::splat(0.5)).is_none() && grid.pmf(0, 0) == 0.0);
        let bad = Grid::new(1, 2, |_, c| if c == 0 { f64::NAN } else { -1.0 });
        assert!(bad.is_empty());
    }

    #[test]
    fn the_last_cell_with_weight_closes_each_sum() {
        let grid = Grid::new(2, 4, |r, c| if r == 0 && c < 2 { 1e-3 } else { 0.0 });
        let s = grid.sample(Vec2::splat(ONE_MINUS_EPSILON)).unwrap();
        assert_eq!((s.row, s.col), (0, 1));
        assert_eq!(grid.pmf(0, 2) + grid.pmf(1, 0), 0.0);
    }
}
