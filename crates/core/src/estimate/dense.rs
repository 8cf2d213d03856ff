//! The dense kernels of the shape fit ([`super::morph_fit`]): symmetric systems stored as
//! square tiles, their Cholesky factorization and solve, weighted Gram matrices, and the
//! products of the basis with a vector, on buffers that a fit keeps from one face to the next.
//!
//! The systems have 40 unknowns or so, where loop overhead and short remainders cost as much
//! as the arithmetic. So a symmetric matrix is a grid of [`TILE`] x [`TILE`] tiles, padded with
//! ones on the diagonal to whole tiles; every loop body is a fixed-size tile operation, which
//! the compiler turns into whole-register arithmetic, and the vectors are whole tiles long.
//!
//! On x86-64 CPUs with AVX2 and FMA (checked at run time, once) the kernels run compiled for
//! them, four lanes wide with fused multiply-adds; elsewhere, as built for the target (SSE2 on
//! x86-64). The two round differently, by a few units in the last place.

/// The side of a tile.
pub(crate) const TILE: usize = 4;

/// A tile: its columns, each [`TILE`] consecutive rows (`t[column][row]`).
pub(crate) type Tile = [[f64; TILE]; TILE];

/// Tiles per side for `d` unknowns.
pub(crate) fn tiles(d: usize) -> usize {
    d.div_ceil(TILE)
}

/// Where entry `(r, c)` of a matrix of `n` x `n` tiles lives: the tile's index (tiles column by
/// column) and the entry's column and row in it.
#[inline(always)]
pub(crate) fn at(n: usize, r: usize, c: usize) -> (usize, usize, usize) {
    ((c / TILE) * n + r / TILE, c % TILE, r % TILE)
}

/// Whether the CPU runs the AVX2 and FMA versions.
#[cfg(target_arch = "x86_64")]
pub(crate) fn wide() -> bool {
    // Cached by std after the first call.
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// `a b + c`, fused where the kernel is compiled for FMA.
#[inline(always)]
pub(crate) fn madd<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// Defines `fn $name`, which runs `$generic::<true>` (the body, written over
/// `const FMA: bool`, with [`madd`] for `a b + c`) compiled for AVX2 and FMA when the CPU has
/// them, else `$generic::<false>` as built. The shape fit defines its per-point passes with it
/// too.
macro_rules! kernel {
    ($(#[$doc:meta])* $vis:vis fn $name:ident / $generic:ident ($($arg:ident: $ty:ty),*) $(-> $ret:ty)? $body:block) => {
        #[inline(always)]
        fn $generic<const FMA: bool>($($arg: $ty),*) $(-> $ret)? $body

        $(#[$doc])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            #[target_feature(enable = "avx2,fma")]
            fn wide_fma($($arg: $ty),*) $(-> $ret)? {
                $generic::<true>($($arg),*)
            }

            #[cfg(target_arch = "x86_64")]
            if $crate::estimate::dense::wide() {
                // SAFETY: `wide_fma` needs AVX2 and FMA, which `wide` has just found.
                return unsafe { wide_fma($($arg),*) };
            }
            $generic::<false>($($arg),*)
        }
    };
}

pub(crate) use kernel;

/// `acc += x yᵀ` for tiles (`x yᵀ` the product of the tiles as matrices, `y` transposed).
#[inline(always)]
fn add_product<const FMA: bool>(acc: &mut Tile, x: &Tile, y: &Tile) {
    for (c, col) in acc.iter_mut().enumerate() {
        for k in 0..TILE {
            let f = y[k][c];
            for r in 0..TILE {
                col[r] = madd::<FMA>(f, x[k][r], col[r]);
            }
        }
    }
}

/// Factors a diagonal tile in place, column by column (lower triangle; false when not
/// positive definite). The lanes of a tile's columns are indexed by row, as the maths reads.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn factor_tile<const FMA: bool>(diag: &mut Tile) -> bool {
    for c in 0..TILE {
        let pivot = diag[c][c];
        if !(pivot > 0.0 && pivot.is_finite()) {
            return false;
        }
        let l = pivot.sqrt();
        let inv = 1.0 / l;
        diag[c][c] = l;
        for r in c + 1..TILE {
            diag[c][r] *= inv;
        }
        for cc in c + 1..TILE {
            let f = -diag[c][cc];
            for r in cc..TILE {
                diag[cc][r] = madd::<FMA>(f, diag[c][r], diag[cc][r]);
            }
        }
    }
    true
}

/// Solves `X Lᵀ = A` in place for a tile `x` under the factored diagonal tile `diag` (`inv` the
/// inverses of its diagonal), column by column of `X`.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn solve_tile<const FMA: bool>(x: &mut Tile, diag: &Tile, inv: &[f64; TILE]) {
    for c in 0..TILE {
        for t in 0..c {
            let f = -diag[t][c];
            for r in 0..TILE {
                x[c][r] = madd::<FMA>(f, x[t][r], x[c][r]);
            }
        }
        for r in 0..TILE {
            x[c][r] *= inv[c];
        }
    }
}

kernel! {
    /// Factors the symmetric matrix of `n` x `n` tiles whose lower triangle `a` holds into
    /// `L Lᵀ`, overwriting that lower triangle with `L` (above the diagonal, the diagonal tiles
    /// are scratch) and writing `1 / L[i][i]` into `inv` (`TILE n` long), for [`solve`]. Returns
    /// false (and leaves `a` partly overwritten) when the matrix is not numerically positive
    /// definite.
    ///
    /// Left-looking by tiles: each tile of a column, from the diagonal down, first loses the
    /// products `X_ik X_jkᵀ` of the solved tiles to its left (summed in registers, then taken off
    /// once), then the diagonal tile is factored and the tiles under it are solved against it.
    pub(crate) fn factor / factor_generic(a: &mut [Tile], n: usize, inv: &mut [f64]) -> bool {
        debug_assert_eq!(a.len(), n * n);
        let (inv, _) = inv.as_chunks_mut::<TILE>();
        for j in 0..n {
            let (left, rest) = a.split_at_mut(j * n);
            let column = &mut rest[j..n];
            for (i, t) in column.iter_mut().enumerate() {
                let i = j + i;
                let mut acc = [[0.0; TILE]; TILE];
                for k in 0..j {
                    add_product::<FMA>(&mut acc, &left[k * n + i], &left[k * n + j]);
                }
                for (col, sub) in t.iter_mut().zip(&acc) {
                    for r in 0..TILE {
                        col[r] -= sub[r];
                    }
                }
            }
            if !factor_tile::<FMA>(&mut column[0]) {
                return false;
            }
            let diag = column[0];
            let inv = &mut inv[j];
            *inv = std::array::from_fn(|c| 1.0 / diag[c][c]);
            for x in &mut column[1..] {
                solve_tile::<FMA>(x, &diag, inv);
            }
        }
        true
    }
}

kernel! {
    /// Solves `L Lᵀ x = b` in place (`b` becomes `x`, `TILE n` long), `l` and `inv` from
    /// [`factor`].
    pub(crate) fn solve / solve_generic(l: &[Tile], n: usize, inv: &[f64], b: &mut [f64]) {
        debug_assert_eq!(b.len(), TILE * n);
        let (b, _) = b.as_chunks_mut::<TILE>();
        let (inv, _) = inv.as_chunks::<TILE>();
        // L y = b, left-looking: each tile of y first loses the products of the solved tiles
        // above it (summed in registers), then is solved against its diagonal tile.
        for j in 0..n {
            let mut acc = [0.0; TILE];
            for (t, yt) in b[..j].iter().enumerate() {
                let x = &l[t * n + j];
                for k in 0..TILE {
                    for r in 0..TILE {
                        acc[r] = madd::<FMA>(yt[k], x[k][r], acc[r]);
                    }
                }
            }
            let diag = &l[j * n + j];
            let mut y: [f64; TILE] = std::array::from_fn(|r| b[j][r] - acc[r]);
            for c in 0..TILE {
                y[c] *= inv[j][c];
                for r in c + 1..TILE {
                    y[r] = madd::<FMA>(-diag[c][r], y[c], y[r]);
                }
            }
            b[j] = y;
        }
        // Lᵀ x = y, from the last tile up: z = y_j - Σ_{i > j} X_ijᵀ x_i, lane by lane first.
        for j in (0..n).rev() {
            let col = &l[j * n + j..(j + 1) * n];
            let mut acc = [[0.0; TILE]; TILE];
            for (x, bi) in col[1..].iter().zip(&b[j + 1..]) {
                for k in 0..TILE {
                    for r in 0..TILE {
                        acc[k][r] = madd::<FMA>(x[k][r], bi[r], acc[k][r]);
                    }
                }
            }
            let diag = &col[0];
            let mut z: [f64; TILE] = std::array::from_fn(|k| {
                b[j][k] - ((acc[k][0] + acc[k][2]) + (acc[k][1] + acc[k][3]))
            });
            for c in (0..TILE).rev() {
                for r in c + 1..TILE {
                    z[c] = madd::<FMA>(-diag[c][r], z[r], z[c]);
                }
                z[c] *= inv[j][c];
            }
            b[j] = z;
        }
    }
}

/// Rows of a tiled system's width, stored by [`TILE`]-wide blocks of columns: block `b` of row
/// `r` is `blocks[b m + r]` (`m` rows), so that a kernel walks one block of every row in turn.
#[derive(Debug, Default)]
pub(crate) struct Rows {
    /// Rows and tiles per row.
    pub(crate) m: usize,
    pub(crate) nt: usize,
    pub(crate) blocks: Vec<[f64; TILE]>,
}

impl Rows {
    /// Room for `m` rows of `nt` tiles (their values left to [`Rows::set`]).
    pub(crate) fn reset(&mut self, m: usize, nt: usize) {
        self.m = m;
        self.nt = nt;
        // Every row is written whole before it is read: no need to clear.
        if self.blocks.len() < m * nt {
            self.blocks.resize(m * nt, [0.0; TILE]);
        }
    }

    /// Writes row `r` from `row` (`TILE nt` values).
    #[cfg(test)]
    fn set(&mut self, r: usize, row: &[f64]) {
        for (b, v) in row.as_chunks::<TILE>().0.iter().enumerate() {
            self.blocks[b * self.m + r] = *v;
        }
    }

    fn block(&self, b: usize) -> &[[f64; TILE]] {
        &self.blocks[b * self.m..(b + 1) * self.m]
    }
}

kernel! {
    /// `out += Σ_r a_rᵀ b_r` on the lower triangle's tiles of the matrix of `n` x `n` tiles
    /// `out`, over the rows of `a` and `b` (rows of `n` tiles): a weighted Gram matrix, `b`
    /// holding `a`'s rows times their weights.
    pub(crate) fn gram / gram_generic(a: &Rows, b: &Rows, out: &mut [Tile]) {
        debug_assert!(b.nt == a.nt && b.m == a.m);
        gram_tiles::<FMA, true>(a, b, out);
    }
}

kernel! {
    /// `out = Σ_r a_rᵀ a_r` on the lower triangle's tiles of the matrix of `n` x `n` tiles
    /// `out` (overwritten; the tiles above the diagonal left as they are), over the rows of `a`
    /// (rows of `n` tiles): the Gram matrix of rows already scaled by the square roots of
    /// their weights.
    pub(crate) fn gram_of / gram_of_generic(a: &Rows, out: &mut [Tile]) {
        gram_tiles::<FMA, false>(a, a, out);
    }
}

/// [`gram`] (`ADD`) or [`gram_of`] (`a` and `b` the same rows): each column of tiles two
/// tiles at a time, which share the broadcasts of `b`'s block, then the one left.
#[inline(always)]
fn gram_tiles<const FMA: bool, const ADD: bool>(a: &Rows, b: &Rows, out: &mut [Tile]) {
    let n = a.nt;
    debug_assert_eq!(out.len(), n * n);
    for (j, col) in out.chunks_exact_mut(n).enumerate() {
        let bj = b.block(j);
        let mut i = j;
        while i + 2 <= n {
            gram_group::<FMA, ADD, 2>(&mut col[i..i + 2], a, i, bj);
            i += 2;
        }
        if i < n {
            gram_group::<FMA, ADD, 1>(&mut col[i..], a, i, bj);
        }
    }
}

/// `G` consecutive tiles `t` of a column, from tile row `i`: `t += Σ_r a_r[i..i + G]ᵀ bj_r`
/// (`t =` unless `ADD`), two rows a turn of the loop.
#[inline(always)]
fn gram_group<const FMA: bool, const ADD: bool, const G: usize>(
    t: &mut [Tile],
    a: &Rows,
    i: usize,
    bj: &[[f64; TILE]],
) {
    let t: &mut [Tile; G] = t.try_into().expect("G tiles");
    let mut acc: [Tile; G] = if ADD { *t } else { [[[0.0; TILE]; TILE]; G] };
    let (bp, bl) = bj.as_chunks::<2>();
    let ai: [&[[f64; TILE]]; G] = std::array::from_fn(|g| a.block(i + g));
    let ap: [&[[[f64; TILE]; 2]]; G] = ai.map(|x| &x.as_chunks::<2>().0[..bp.len()]);
    for (p, b2) in bp.iter().enumerate() {
        for (h, bh) in b2.iter().enumerate() {
            for c in 0..TILE {
                for g in 0..G {
                    for l in 0..TILE {
                        acc[g][c][l] = madd::<FMA>(bh[c], ap[g][p][h][l], acc[g][c][l]);
                    }
                }
            }
        }
    }
    if let [bh] = bl {
        let r = 2 * bp.len();
        for c in 0..TILE {
            for g in 0..G {
                for l in 0..TILE {
                    acc[g][c][l] = madd::<FMA>(bh[c], ai[g][r][l], acc[g][c][l]);
                }
            }
        }
    }
    *t = acc;
}

kernel! {
    /// Columns `0..6` of the matrix of `n` x `n` tiles `out`, from row tile 1 down: column `c`
    /// is `Σ_t f[c][t] v_t`, the `v_t` columns of `n` tiles (`v[t n..(t + 1) n]`).
    pub(crate) fn combine_columns / combine_columns_generic(out: &mut [Tile], n: usize, f: [[f64; 12]; 6], v: &[[f64; TILE]]) {
        debug_assert_eq!(v.len(), 12 * n);
        for rt in 1..n {
            let vs: [[f64; TILE]; 12] = std::array::from_fn(|t| v[t * n + rt]);
            for (c, fc) in f.iter().enumerate() {
                let mut col = [0.0; TILE];
                for (vt, &ft) in vs.iter().zip(fc) {
                    for r in 0..TILE {
                        col[r] = madd::<FMA>(ft, vt[r], col[r]);
                    }
                }
                out[(c / TILE) * n + rt][c % TILE] = col;
            }
        }
    }
}

kernel! {
    /// `out = Σ_t f[t] m[t]` on the lower triangle's tiles of matrices of `n` x `n` tiles, from
    /// tile column `from` (the earlier columns of `out` left as they are).
    pub(crate) fn combine6 / combine6_generic(out: &mut [Tile], n: usize, from: usize, f: [f64; 6], m: [&[Tile]; 6]) {
        for j in from..n {
            for i in j..n {
                let k = j * n + i;
                let mut t = [[0.0; TILE]; TILE];
                for (mt, ft) in m.iter().zip(f) {
                    let s = &mt[k];
                    for c in 0..TILE {
                        for r in 0..TILE {
                            t[c][r] = madd::<FMA>(ft, s[c][r], t[c][r]);
                        }
                    }
                }
                out[k] = t;
            }
        }
    }
}

kernel! {
    /// `out[j] = Σ_r x[r] rows[r stride + j]` for every `j < out.len()`: a vector times a
    /// matrix of rows (`stride` a multiple of [`TILE`], at least `out.len()` rounded up to a
    /// multiple of 4 tiles, zeros in the padding), sixteen columns at a time in registers.
    pub(crate) fn rows_times / rows_times_generic(rows: &[f64], stride: usize, x: &[f64], out: &mut [f64]) {
        const GROUP: usize = 4;
        let kk = out.len();
        for g in (0..tiles(kk)).step_by(GROUP) {
            let mut acc = [[0.0; TILE]; GROUP];
            for (row, &xr) in rows.chunks_exact(stride).zip(x) {
                let (ch, _) = row[TILE * g..TILE * (g + GROUP)].as_chunks::<TILE>();
                for q in 0..GROUP {
                    for l in 0..TILE {
                        acc[q][l] = madd::<FMA>(xr, ch[q][l], acc[q][l]);
                    }
                }
            }
            for (o, v) in out[TILE * g..].iter_mut().zip(acc.as_flattened()) {
                *o = *v;
            }
        }
    }
}

kernel! {
    /// `x += Σ_j f[j] col_j` over `j < f.len()`, `col_j = cols[j len..(j + 1) len]` with
    /// `len = x.len()`, a multiple of [`TILE`]: four columns per pass over `x`, the last pass
    /// taking the one to three left.
    pub(crate) fn add_columns / add_columns_generic(x: &mut [f64], cols: &[f64], f: &[f64]) {
        let len = x.len();
        debug_assert_eq!(len % TILE, 0);
        let (xs, _) = x.as_chunks_mut::<TILE>();
        let col = |j: usize| cols[j * len..(j + 1) * len].as_chunks::<TILE>().0;
        let (groups, rest) = f.as_chunks::<4>();
        for (g, &fq) in groups.iter().enumerate() {
            add_group::<FMA, 4>(xs, std::array::from_fn(|q| col(4 * g + q)), fq);
        }
        let j = 4 * groups.len();
        match *rest {
            [f0] => add_group::<FMA, 1>(xs, [col(j)], [f0]),
            [f0, f1] => add_group::<FMA, 2>(xs, [col(j), col(j + 1)], [f0, f1]),
            [f0, f1, f2] => add_group::<FMA, 3>(xs, [col(j), col(j + 1), col(j + 2)], [f0, f1, f2]),
            _ => {}
        }
    }
}

/// `x += Σ_q f[q] c[q]` in one pass over `x`.
#[inline(always)]
fn add_group<const FMA: bool, const N: usize>(
    x: &mut [[f64; TILE]],
    c: [&[[f64; TILE]]; N],
    f: [f64; N],
) {
    for (i, xi) in x.iter_mut().enumerate() {
        for q in 0..N {
            let cq = &c[q][i];
            for r in 0..TILE {
                xi[r] = madd::<FMA>(f[q], cq[r], xi[r]);
            }
        }
    }
}

kernel! {
    /// `y += a x` (over the shorter of the two).
    pub(crate) fn axpy / axpy_generic(a: f64, x: &[f64], y: &mut [f64]) {
        axpy_::<FMA>(a, x, y)
    }
}

/// `y += a x` (over the shorter of the two).
#[inline(always)]
fn axpy_<const FMA: bool>(a: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi = madd::<FMA>(a, *xi, *yi);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};
    use proptest::prelude::*;

    /// A random symmetric positive-definite matrix `M Mᵀ + δ I` and a right-hand side.
    fn spd(d: usize, entries: &[f64], shift: f64) -> (DMatrix<f64>, DVector<f64>) {
        let m = DMatrix::from_fn(d, d, |i, j| entries[(i * d + j) % entries.len()]);
        let a = &m * m.transpose() + DMatrix::identity(d, d) * shift;
        let b = DVector::from_fn(d, |i, _| entries[(7 * i + 3) % entries.len()]);
        (a, b)
    }

    /// `a` as tiles, ones on the diagonal of the padding; the upper triangle set to `above`.
    fn tiled(a: &DMatrix<f64>, above: f64) -> (Vec<Tile>, usize) {
        let d = a.nrows();
        let n = tiles(d);
        let mut out = vec![[[0.0; TILE]; TILE]; n * n];
        for c in 0..TILE * n {
            for r in 0..TILE * n {
                let (k, tc, tr) = at(n, r, c);
                out[k][tc][tr] = if r < c {
                    above
                } else if r < d && c < d {
                    a[(r, c)]
                } else {
                    f64::from(u8::from(r == c))
                };
            }
        }
        (out, n)
    }

    /// Both builds of the kernels where the CPU has AVX2 and FMA, else the one it runs.
    fn builds() -> Vec<bool> {
        #[cfg(target_arch = "x86_64")]
        if wide() {
            return vec![false, true];
        }
        vec![false]
    }

    /// The factorization and solve of one build.
    fn factor_solve(wide: bool, a: &mut [Tile], n: usize, b: &mut [f64]) -> bool {
        #[cfg(target_arch = "x86_64")]
        if wide {
            #[target_feature(enable = "avx2,fma")]
            fn run(a: &mut [Tile], n: usize, b: &mut [f64]) -> bool {
                let mut inv = vec![0.0; TILE * n];
                factor_generic::<true>(a, n, &mut inv) && {
                    solve_generic::<true>(a, n, &inv, b);
                    true
                }
            }
            // SAFETY: `builds` offers the wide build only where the CPU has it.
            return unsafe { run(a, n, b) };
        }
        let _ = wide;
        let mut inv = vec![0.0; TILE * n];
        factor_generic::<false>(a, n, &mut inv) && {
            solve_generic::<false>(a, n, &inv, b);
            true
        }
    }

    proptest! {
        /// Both builds agree with nalgebra's Cholesky, with residuals at rounding level, for
        /// every size up to past the default model's 40 unknowns; the upper triangle is not
        /// read and the padding's unknowns come out zero.
        #[test]
        fn solves_random_spd_systems(
            d in 1usize..70,
            entries in prop::collection::vec(-3.0f64..3.0, 16..200),
            shift in 1e-3f64..10.0,
        ) {
            let (a, b) = spd(d, &entries, shift);
            let want = a.clone().cholesky().unwrap().solve(&b);
            for wide in builds() {
                let (mut t, n) = tiled(&a, f64::NAN);
                let mut x = b.as_slice().to_vec();
                x.resize(TILE * n, 0.0);
                prop_assert!(factor_solve(wide, &mut t, n, &mut x));
                prop_assert!(x[d..].iter().all(|&v| v == 0.0));
                let x = DVector::from_column_slice(&x[..d]);
                let scale = want.norm().max(1e-300);
                prop_assert!((&x - &want).norm() <= 1e-8 * scale, "{} vs {}", x, want);
                prop_assert!((&a * &x - &b).norm() <= 1e-9 * (a.norm() * x.norm() + b.norm()));
            }
        }

        /// The Gram matrix, the combination of tiled matrices and the products against the
        /// basis equal their plain sums.
        #[test]
        fn products_match_plain_sums(
            n in 1usize..7,
            k in 0usize..11,
            rows in 0usize..9,
            v in prop::collection::vec(-10.0f64..10.0, 600),
        ) {
            let len = TILE * n;
            let (a, b) = (&v[..rows * len], &v[200..200 + rows * len]);
            let (mut ra, mut rb) = (Rows::default(), Rows::default());
            ra.reset(rows, n);
            rb.reset(rows, n);
            for q in 0..rows {
                ra.set(q, &a[q * len..(q + 1) * len]);
                rb.set(q, &b[q * len..(q + 1) * len]);
            }
            // `gram` adds to what is there; `gram_of` overwrites the lower triangle.
            let mut g = vec![[[1.0; TILE]; TILE]; n * n];
            gram(&ra, &rb, &mut g);
            let mut gs = vec![[[f64::NAN; TILE]; TILE]; n * n];
            gram_of(&ra, &mut gs);
            // The build as for the target, which the dispatch above may not take.
            let mut gp = vec![[[f64::NAN; TILE]; TILE]; n * n];
            gram_of_generic::<false>(&ra, &mut gp);
            for c in 0..len {
                for r in c..len {
                    let (t, tc, tr) = at(n, r, c);
                    let want: f64 = 1.0 + (0..rows).map(|q| a[q * len + r] * b[q * len + c]).sum::<f64>();
                    prop_assert!((g[t][tc][tr] - want).abs() <= 1e-9 * (1.0 + want.abs()));
                    let want: f64 = (0..rows).map(|q| a[q * len + r] * a[q * len + c]).sum();
                    prop_assert!((gs[t][tc][tr] - want).abs() <= 1e-9 * (1.0 + want.abs()));
                    prop_assert!((gp[t][tc][tr] - want).abs() <= 1e-9 * (1.0 + want.abs()));
                }
            }

            let m: Vec<Vec<Tile>> = (0..6)
                .map(|t| {
                    (0..n * n)
                        .map(|q| std::array::from_fn(|c| std::array::from_fn(|r| v[(t * 61 + q * 16 + c * 4 + r) % 600])))
                        .collect()
                })
                .collect();
            let f = [1.0, -2.0, 0.5, 3.0, -1.5, 0.25];
            let mut out = vec![[[0.0; TILE]; TILE]; n * n];
            combine6(&mut out, n, 0, f, std::array::from_fn(|t| &m[t][..]));
            for j in 0..n {
                for i in j..n {
                    for c in 0..TILE {
                        for r in 0..TILE {
                            let want: f64 = (0..6).map(|t| f[t] * m[t][j * n + i][c][r]).sum();
                            prop_assert!((out[j * n + i][c][r] - want).abs() <= 1e-9 * (1.0 + want.abs()));
                        }
                    }
                }
            }

            let cols = &v[..k * len];
            let x = &v[400..400 + len];
            let f = &v[500..500 + k];
            let mut y = x.to_vec();
            add_columns(&mut y, cols, f);
            for r in 0..len {
                let want = x[r] + (0..k).map(|j| f[j] * cols[j * len + r]).sum::<f64>();
                prop_assert!((y[r] - want).abs() <= 1e-9 * (1.0 + want.abs()));
            }
            // k values from `len` rows of 16 (k at most 11, in one group of sixteen).
            let mut out = vec![0.0; k];
            rows_times(&v[..16 * len], 16, x, &mut out);
            for j in 0..k {
                let want: f64 = (0..len).map(|r| v[r * 16 + j] * x[r]).sum();
                prop_assert!((out[j] - want).abs() <= 1e-9 * (1.0 + want.abs()));
            }
        }
    }

    #[test]
    fn indefinite_and_non_finite_matrices_are_refused() {
        for (a, ok) in [
            // Eigenvalues 3 and -1.
            (DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]), false),
            (
                DMatrix::from_row_slice(2, 2, &[f64::NAN, 0.0, 0.0, 1.0]),
                false,
            ),
            (DMatrix::zeros(3, 3), false),
            (DMatrix::identity(5, 5), true),
        ] {
            let (mut t, n) = tiled(&a, 0.0);
            assert_eq!(factor(&mut t, n, &mut vec![0.0; TILE * n]), ok, "{a}");
        }
    }
}
