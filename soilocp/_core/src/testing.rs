//! What the kernels' unit tests share.

/// Assert that `got` is within `tol` of `want`, naming the three.
pub fn close(got: f64, want: f64, tol: f64) {
    assert!((got - want).abs() <= tol, "got {got}, want {want} (tol {tol})");
}
