//! The small dense linear algebra the estimate needs: the eigenvectors of a
//! symmetric matrix (a probe's axes, a pose's uncertainty) and a Cholesky
//! solve (the outline's correlated errors).

/// Eigenvalues and unit eigenvectors (`vectors[k]` belongs to `values[k]`)
/// of a symmetric `N x N` matrix, by cyclic Jacobi rotations.
pub fn symmetric_eigen<const N: usize>(mut a: [[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
    let mut v: [[f64; N]; N] = std::array::from_fn(|i| std::array::from_fn(|j| (i == j) as u8 as f64));
    for _ in 0..50 {
        let off: f64 = (0..N)
            .flat_map(|p| (p + 1..N).map(move |q| (p, q)))
            .map(|(p, q)| a[p][q].abs())
            .sum();
        let scale: f64 = (0..N).map(|k| a[k][k].abs()).sum();
        if off <= 1e-15 * scale {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = 0.5 * (a[q][q] - a[p][p]) / a[p][q];
                // The smaller root of t^2 + 2 theta t - 1 = 0 (1 for theta 0).
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let (c, s) = (1.0 / (t * t + 1.0).sqrt(), t / (t * t + 1.0).sqrt());
                // A <- J^T A J and V <- V J, J the rotation in the (p, q) plane.
                let rotate_columns = |m: &mut [[f64; N]; N]| {
                    for row in m.iter_mut() {
                        let (mp, mq) = (row[p], row[q]);
                        row[p] = c * mp - s * mq;
                        row[q] = s * mp + c * mq;
                    }
                };
                rotate_columns(&mut a);
                rotate_columns(&mut v);
                let (ap, aq) = (a[p], a[q]);
                a[p] = std::array::from_fn(|k| c * ap[k] - s * aq[k]);
                a[q] = std::array::from_fn(|k| s * ap[k] + c * aq[k]);
            }
        }
    }
    // Eigenvector k is column k of v.
    let vectors = std::array::from_fn(|k| std::array::from_fn(|i| v[i][k]));
    (std::array::from_fn(|k| a[k][k]), vectors)
}

/// The Cholesky factor `L` (lower, row-major `n x n`, `A = L L^T`) of the
/// symmetric positive definite `a`; None when `a` is not.
pub fn cholesky(a: &[f64], n: usize) -> Option<Vec<f64>> {
    assert_eq!(a.len(), n * n, "cholesky: {} entries for {n} x {n}", a.len());
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let sum: f64 = (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum();
            if i == j {
                let d = a[i * n + i] - sum;
                if d <= 0.0 || !d.is_finite() {
                    return None;
                }
                l[i * n + i] = d.sqrt();
            } else {
                l[i * n + j] = (a[i * n + j] - sum) / l[j * n + j];
            }
        }
    }
    Some(l)
}

/// `x` with `L L^T x = b`, `l` from [`cholesky`].
pub fn cholesky_solve(l: &[f64], n: usize, b: &[f64]) -> Vec<f64> {
    let mut y = vec![0.0; n];
    for i in 0..n {
        y[i] = (b[i] - (0..i).map(|k| l[i * n + k] * y[k]).sum::<f64>()) / l[i * n + i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        x[i] = (y[i] - (i + 1..n).map(|k| l[k * n + i] * x[k]).sum::<f64>()) / l[i * n + i];
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_eigen_decomposition_rebuilds_its_matrix() {
        let a = [[2.0, -0.7, 0.3], [-0.7, 1.1, 0.05], [0.3, 0.05, 0.4]];
        let b: [[f64; 6]; 6] =
            std::array::from_fn(|i| std::array::from_fn(|j| 1.0 / (1.0 + i as f64 + j as f64) + (i == j) as u8 as f64));
        fn check<const N: usize>(a: [[f64; N]; N]) {
            let (values, vectors) = symmetric_eigen(a);
            for i in 0..N {
                for j in 0..N {
                    let rebuilt: f64 = (0..N).map(|k| values[k] * vectors[k][i] * vectors[k][j]).sum();
                    assert!(
                        (rebuilt - a[i][j]).abs() < 1e-12,
                        "({i}, {j}): {rebuilt} against {}",
                        a[i][j]
                    );
                    let dot: f64 = (0..N).map(|k| vectors[i][k] * vectors[j][k]).sum();
                    assert!((dot - (i == j) as u8 as f64).abs() < 1e-12);
                }
            }
        }
        check(a);
        check(b);
    }

    #[test]
    fn a_cholesky_solve_inverts_its_matrix_and_refuses_an_indefinite_one() {
        let a = [4.0, 2.0, 0.4, 2.0, 3.0, 0.5, 0.4, 0.5, 2.0];
        let l = cholesky(&a, 3).expect("positive definite");
        let x = cholesky_solve(&l, 3, &[1.0, -2.0, 0.5]);
        for i in 0..3 {
            let ax: f64 = (0..3).map(|k| a[i * 3 + k] * x[k]).sum();
            assert!((ax - [1.0, -2.0, 0.5][i]).abs() < 1e-12);
        }
        assert!(cholesky(&[1.0, 2.0, 2.0, 1.0], 2).is_none());
    }
}
