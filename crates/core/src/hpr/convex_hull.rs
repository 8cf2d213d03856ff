//! Which points of a 3D cloud are vertices of its convex hull (incremental hull, O(n²)).
//!
//! Written here because the crates that do this either need libclang at build time (qhull
//! bindings) or fail on round-off for the nearly co-spherical clouds that spherical flipping
//! makes (chull). Points within a relative tolerance of the hull count as inside.

use std::collections::HashSet;

use nalgebra::Vector3;

use crate::error::{Error, Result};

/// For each point, whether it is a vertex of the convex hull.
pub fn hull_vertices(points: &[Vector3<f64>]) -> Result<Vec<bool>> {
    let n = points.len();
    if n < 4 {
        return Err(Error::too_few("convex hull", 4, n));
    }
    let scale = points
        .iter()
        .map(|p| p.amax())
        .fold(0.0, f64::max)
        .max(1e-300);
    let eps = 1e-12 * scale * scale * scale;
    let orient = |f: &[usize; 3], p: &Vector3<f64>| -> f64 {
        let (a, b, c) = (points[f[0]], points[f[1]], points[f[2]]);
        (b - a).cross(&(c - a)).dot(&(p - a))
    };

    // Initial tetrahedron: two far apart points, the farthest from their line, the farthest
    // from that plane.
    let i0 = 0;
    let i1 = (0..n)
        .max_by(|&a, &b| {
            (points[a] - points[i0])
                .norm_squared()
                .total_cmp(&(points[b] - points[i0]).norm_squared())
        })
        .unwrap_or(0);
    let d01 = points[i1] - points[i0];
    let i2 = (0..n)
        .max_by(|&a, &b| {
            d01.cross(&(points[a] - points[i0]))
                .norm_squared()
                .total_cmp(&d01.cross(&(points[b] - points[i0])).norm_squared())
        })
        .unwrap_or(0);
    let i3 = (0..n)
        .max_by(|&a, &b| {
            orient(&[i0, i1, i2], &points[a])
                .abs()
                .total_cmp(&orient(&[i0, i1, i2], &points[b]).abs())
        })
        .unwrap_or(0);
    if orient(&[i0, i1, i2], &points[i3]).abs() <= eps || i1 == i0 || i2 == i0 || i2 == i1 {
        return Err(Error::Degenerate("the points are coplanar".into()));
    }
    let mut faces: Vec<[usize; 3]> = if orient(&[i0, i1, i2], &points[i3]) > 0.0 {
        vec![[i0, i2, i1], [i0, i1, i3], [i1, i2, i3], [i2, i0, i3]]
    } else {
        vec![[i0, i1, i2], [i0, i3, i1], [i1, i3, i2], [i2, i3, i0]]
    };

    let mut visible_edges: HashSet<(usize, usize)> = HashSet::new();
    let mut keep = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if [i0, i1, i2, i3].contains(&i) {
            continue;
        }
        visible_edges.clear();
        keep.clear();
        for f in &faces {
            if orient(f, p) > eps {
                visible_edges.extend([(f[0], f[1]), (f[1], f[2]), (f[2], f[0])]);
            } else {
                keep.push(*f);
            }
        }
        if visible_edges.is_empty() {
            continue;
        }
        // Horizon: edges of visible faces whose twin belongs to a face that stays.
        for &(a, b) in &visible_edges {
            if !visible_edges.contains(&(b, a)) {
                keep.push([a, b, i]);
            }
        }
        std::mem::swap(&mut faces, &mut keep);
    }
    let mut on_hull = vec![false; n];
    for f in &faces {
        for &v in f {
            on_hull[v] = true;
        }
    }
    Ok(on_hull)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_corners_are_the_hull_and_the_centre_is_not() {
        let mut pts: Vec<Vector3<f64>> = (0..8)
            .map(|k| Vector3::new((k & 1) as f64, ((k >> 1) & 1) as f64, ((k >> 2) & 1) as f64))
            .collect();
        pts.push(Vector3::new(0.5, 0.5, 0.5));
        pts.push(Vector3::new(0.5, 0.5, 0.0)); // on a face: not a vertex
        let h = hull_vertices(&pts).unwrap();
        assert_eq!(h, [vec![true; 8], vec![false, false]].concat());
    }

    #[test]
    fn coplanar_points_are_an_error() {
        let pts: Vec<_> = (0..6)
            .map(|k| Vector3::new(k as f64, (k * k) as f64, 0.0))
            .collect();
        assert!(hull_vertices(&pts).is_err());
    }
}
