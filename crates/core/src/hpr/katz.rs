//! The Katz-Tal-Basri baseline ("Direct visibility of point sets", SIGGRAPH 2007): spherical
//! flipping of the points about a sphere centred at the camera, then the points on the convex
//! hull of the flipped set plus the camera are the visible ones.

use nalgebra::Vector3;

use super::convex_hull::hull_vertices;
use crate::error::{Error, Result};

/// Parameters of the spherical-flipping operator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KatzHpr {
    /// Camera distance from the shape's centroid along +z, in multiples of the shape radius.
    pub camera_distance: f64,
    /// The flipping radius is `max ‖p - C‖ · 10^gamma`.
    pub gamma: f64,
}

impl Default for KatzHpr {
    fn default() -> Self {
        KatzHpr {
            camera_distance: 10.0,
            gamma: 2.0,
        }
    }
}

impl KatzHpr {
    /// Visibility of each point of `rotated` (camera frame) from a camera on the +z axis.
    pub fn visibility(&self, rotated: &[Vector3<f64>]) -> Result<Vec<bool>> {
        if rotated.len() < 4 {
            return Err(Error::too_few("spherical-flipping HPR", 4, rotated.len()));
        }
        if rotated.iter().any(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(Error::non_finite("HPR points"));
        }
        if !(self.camera_distance > 0.0 && self.gamma.is_finite()) {
            return Err(Error::param(
                "camera_distance",
                "must be positive, with a finite gamma",
            ));
        }
        let c = rotated.iter().sum::<Vector3<f64>>() / rotated.len() as f64;
        let radius = rotated.iter().map(|p| (p - c).norm()).fold(0.0, f64::max);
        if radius <= 0.0 {
            return Err(Error::Degenerate("all points coincide".into()));
        }
        let camera = c + Vector3::new(0.0, 0.0, self.camera_distance * radius);
        let rel: Vec<Vector3<f64>> = rotated.iter().map(|p| p - camera).collect();
        let max_norm = rel.iter().map(|p| p.norm()).fold(0.0, f64::max);
        let big_r = max_norm * 10f64.powf(self.gamma);
        let mut flipped: Vec<Vector3<f64>> = rel
            .iter()
            .map(|p| {
                let n = p.norm().max(1e-300);
                // Divided by the radius to keep the hull's tolerance in scale.
                (p + 2.0 * (big_r - n) * p / n) / big_r
            })
            .collect();
        flipped.push(Vector3::zeros());
        let mut visible = hull_vertices(&flipped)?;
        visible.pop();
        Ok(visible)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sees_the_near_side_of_a_sphere() {
        // Points on a unit sphere: the ones facing the camera (+z) are visible, the far ones not.
        let mut pts = Vec::new();
        for i in 0..12 {
            for j in 1..12 {
                let (th, ph) = (
                    i as f64 * std::f64::consts::TAU / 12.0,
                    j as f64 * std::f64::consts::PI / 12.0,
                );
                pts.push(Vector3::new(
                    ph.sin() * th.cos(),
                    ph.sin() * th.sin(),
                    ph.cos(),
                ));
            }
        }
        let vis = KatzHpr::default().visibility(&pts).unwrap();
        for (p, v) in pts.iter().zip(&vis) {
            if p.z > 0.3 {
                assert!(v, "{p:?} should be visible");
            }
            if p.z < -0.3 {
                assert!(!v, "{p:?} should be hidden");
            }
        }
    }
}
