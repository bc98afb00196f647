//! Transforms as the crate takes them from callers: finite, and invertible where a query must map back.

use crate::{Error, Result};
use glam::Affine3A;

/// `t` itself when every entry is finite, else [`Error::InvalidTransform`]. For transforms that are only
/// ever applied forwards (a zero scale is legal there). Cost: 12 comparisons.
pub(crate) fn check_finite(t: &Affine3A) -> Result<Affine3A> {
    if t.is_finite() {
        Ok(*t)
    } else {
        Err(Error::InvalidTransform(format!("{t:?}")))
    }
}

/// The inverse of `t` when `t` is finite and invertible (a non-zero, finite determinant and a finite
/// inverse), else [`Error::InvalidTransform`]. For transforms that map world space back into a mesh's
/// object space. Cost: one 3×3 inverse.
pub(crate) fn checked_inverse(t: &Affine3A) -> Result<Affine3A> {
    check_finite(t)?;
    let det = t.matrix3.determinant();
    let inverse = t.inverse();
    if det != 0.0 && det.is_finite() && inverse.is_finite() {
        Ok(inverse)
    } else {
        Err(Error::InvalidTransform(format!("{t:?} cannot be inverted")))
    }
}
