//! Geometry of the virtual rig: pinhole devices and ray casting against the analytic surfaces.
//!
//! Pixel coordinates put pixel centres at integers: column x covers [x − ½, x + ½], so the
//! frame spans [−½, width − ½]. That is the align-corners=true convention of the sampling grids
//! (normalised −1 and +1 are the centres of the first and last pixels).

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::scene::{Pose, SURFACE_EXTENT, Surface};

pub(crate) type V3 = Vector3<f64>;

/// A pinhole camera or projector: square pixels, principal point at the frame centre.
#[derive(Clone, Debug)]
pub(crate) struct Pinhole {
    pub width: usize,
    pub height: usize,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    /// Device-to-world rotation.
    pub rot: Matrix3<f64>,
    /// Optical centre, world metres.
    pub centre: V3,
}

impl Pinhole {
    pub fn new(width: usize, height: usize, hfov_deg: f64, pose: &Pose) -> Self {
        let f = (width as f64 / 2.0) / (hfov_deg.to_radians() / 2.0).tan();
        Pinhole {
            width,
            height,
            f,
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
            rot: rotation(&pose.rotation_deg),
            centre: V3::from(pose.position),
        }
    }

    /// World direction of the ray through pixel coordinate (x, y) (device z component 1).
    pub fn ray(&self, x: f64, y: f64) -> V3 {
        self.rot * V3::new((x - self.cx) / self.f, (y - self.cy) / self.f, 1.0)
    }

    /// Pixel coordinate of world point `p`, or `None` when it is not in front of the device.
    pub fn project(&self, p: &V3) -> Option<(f64, f64)> {
        let q = self.rot.transpose() * (p - self.centre);
        (q.z > 1e-9).then(|| (self.f * q.x / q.z + self.cx, self.f * q.y / q.z + self.cy))
    }

    /// Squared radius from the frame centre, 1 at the corners.
    pub fn radius2(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (
            (x - self.cx) / (self.cx + 0.5),
            (y - self.cy) / (self.cy + 0.5),
        );
        (dx * dx + dy * dy) / 2.0
    }
}

/// R = Ry(yaw)·Rx(pitch)·Rz(roll), device to world; see [`Pose`].
pub(crate) fn rotation(deg: &[f64; 3]) -> Matrix3<f64> {
    let [yaw, pitch, roll] = deg.map(f64::to_radians);
    let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), yaw);
    // A rotation by +pitch about x maps +z to (0, −sin, cos): towards −y, up (y points down).
    let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), pitch);
    let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), roll);
    (ry * rx * rz).into_inner()
}

/// A surface ready for ray casting: the height field with its trigonometry precomputed, its
/// depth range, and normals.
#[derive(Clone, Debug)]
pub(crate) struct Shape {
    field: Field,
    z_min: f64,
    z_max: f64,
}

/// [`Surface`] with constants precomputed for fast evaluation.
#[derive(Clone, Copy, Debug)]
enum Field {
    Plane {
        d: f64,
        sx: f64,
        sy: f64,
    },
    Cylinder {
        d: f64,
        r: f64,
        sign: f64,
    },
    Wave {
        d: f64,
        a: f64,
        kx: f64,
        ky: f64,
        phase: f64,
    },
    Corner {
        d: f64,
        slope: f64,
        edge: f64,
    },
    Step {
        d: f64,
        depth: f64,
        edge: f64,
    },
}

/// Coarse steps through the depth slab before bisection.
const MARCH_STEPS: usize = 64;
const BISECT_STEPS: usize = 48;

impl Shape {
    pub fn new(surface: &Surface) -> Self {
        let e = SURFACE_EXTENT;
        let field = match *surface {
            Surface::Plane { distance, tilt_deg } => Field::Plane {
                d: distance,
                sx: tilt_deg[0].to_radians().tan(),
                sy: tilt_deg[1].to_radians().tan(),
            },
            Surface::Cylinder {
                distance,
                radius,
                convex,
            } => Field::Cylinder {
                d: distance,
                r: radius.abs(),
                sign: if convex { 1.0 } else { -1.0 },
            },
            Surface::Wave {
                distance,
                amplitude,
                period,
                angle_deg,
                phase_deg,
            } => {
                let k = std::f64::consts::TAU / period;
                Field::Wave {
                    d: distance,
                    a: amplitude,
                    kx: k * angle_deg.to_radians().cos(),
                    ky: k * angle_deg.to_radians().sin(),
                    phase: phase_deg.to_radians(),
                }
            }
            Surface::Corner {
                distance,
                slope,
                edge_x,
            } => Field::Corner {
                d: distance,
                slope,
                edge: edge_x,
            },
            Surface::Step {
                distance,
                depth,
                edge_x,
            } => Field::Step {
                d: distance,
                depth,
                edge: edge_x,
            },
        };
        let (z_min, z_max) = match field {
            Field::Plane { d, sx, sy } => {
                let s = (sx.abs() + sy.abs()) * e;
                (d - s, d + s)
            }
            Field::Cylinder { d, r, sign } => {
                let sag = r - (r * r - cyl_x(e, r).powi(2)).sqrt();
                if sign > 0.0 {
                    (d, d + sag)
                } else {
                    (d - sag, d)
                }
            }
            Field::Wave { d, a, .. } => (d - a.abs(), d + a.abs()),
            Field::Corner { d, slope, edge } => {
                let far = slope.abs() * (e + edge.abs());
                (d - far, d + far)
            }
            Field::Step { d, depth, .. } => (d - depth.abs(), d + depth.abs()),
        };
        Shape {
            field,
            z_min: z_min - 1e-3,
            z_max: z_max + 1e-3,
        }
    }

    /// Height z = h(x, y) of the surface (metres).
    #[inline]
    pub fn height(&self, x: f64, y: f64) -> f64 {
        let e = SURFACE_EXTENT;
        let (x, y) = (x.clamp(-e, e), y.clamp(-e, e));
        match self.field {
            Field::Plane { d, sx, sy } => d + sx * x + sy * y,
            Field::Cylinder { d, r, sign } => {
                let xc = cyl_x(x, r);
                d + sign * (r - (r * r - xc * xc).sqrt())
            }
            Field::Wave {
                d,
                a,
                kx,
                ky,
                phase,
            } => d + a * (kx * x + ky * y + phase).sin(),
            Field::Corner { d, slope, edge } => d - slope * (x - edge).abs(),
            Field::Step { d, depth, edge } => {
                if x >= edge {
                    d - depth
                } else {
                    d
                }
            }
        }
    }

    /// Unit normal at surface point `p`, facing the camera side (−z), or the face's normal on
    /// the vertical face of a step.
    pub fn normal(&self, p: &V3) -> V3 {
        if let Field::Step { d, depth, edge } = self.field {
            let (lo, hi) = (d - depth.max(0.0), d - depth.min(0.0));
            let tol = 1e-7 * (1.0 + d.abs());
            if p.z > lo + tol && p.z < hi - tol && (p.x - edge).abs() < 1e-5 {
                // The vertical face looks towards the side of the farther level.
                return if depth >= 0.0 {
                    V3::new(-1.0, 0.0, 0.0)
                } else {
                    V3::new(1.0, 0.0, 0.0)
                };
            }
        }
        // Central differences of the height field (exact enough for smooth pieces; the corner's
        // crease and the step's edges are measure-zero).
        let h = 1e-6;
        let (x, y) = (p.x, p.y);
        let dzdx = (self.height(x + h, y) - self.height(x - h, y)) / (2.0 * h);
        let dzdy = (self.height(x, y + h) - self.height(x, y - h)) / (2.0 * h);
        let dzdx = if dzdx.is_finite() && dzdx.abs() < 1e3 {
            dzdx
        } else {
            0.0
        };
        let dzdy = if dzdy.is_finite() && dzdy.abs() < 1e3 {
            dzdy
        } else {
            0.0
        };
        V3::new(dzdx, dzdy, -1.0).normalize()
    }

    /// `z − h(x, y)` at `p`: negative in front of the surface, non-negative inside the solid.
    fn inside(&self, p: &V3) -> f64 {
        p.z - self.height(p.x, p.y)
    }

    /// First intersection of the ray `o + t·d` (t > 0) with the surface, as the parameter t.
    /// The ray must travel towards +z. `None` when it does not reach the surface.
    pub fn intersect(&self, o: &V3, d: &V3) -> Option<f64> {
        if d.z <= 1e-12 {
            return None;
        }
        let t0 = ((self.z_min - o.z) / d.z).max(0.0);
        let t1 = (self.z_max - o.z) / d.z;
        if t1 <= t0 {
            return None;
        }
        let at = |t: f64| self.inside(&(o + d * t));
        if at(t0) >= 0.0 {
            return Some(t0);
        }
        let mut lo = t0;
        let mut hi = None;
        for i in 1..=MARCH_STEPS {
            let t = t0 + (t1 - t0) * i as f64 / MARCH_STEPS as f64;
            if at(t) >= 0.0 {
                hi = Some(t);
                break;
            }
            lo = t;
        }
        let mut hi = hi?;
        for _ in 0..BISECT_STEPS {
            let mid = 0.5 * (lo + hi);
            if at(mid) >= 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Some(hi)
    }

    /// Whether the segment from `from` to surface point `p` reaches `p` unblocked.
    pub fn reaches(&self, from: &V3, p: &V3) -> bool {
        let d = p - from;
        match self.intersect(from, &d) {
            // Blocked when the first hit is clearly before p (relative tolerance along the ray).
            Some(t) => t >= 1.0 - 1e-6,
            None => true,
        }
    }
}

/// x clamped to where the cylinder's slope stays moderate (|x| ≤ 0.9·radius).
fn cyl_x(x: f64, radius: f64) -> f64 {
    let lim = 0.9 * radius.abs();
    x.clamp(-lim, lim)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pinhole_projects_its_own_rays_back() {
        let pose = Pose {
            position: [0.1, -0.05, 0.02],
            rotation_deg: [-3.0, 1.5, 0.7],
        };
        let cam = Pinhole::new(80, 60, 45.0, &pose);
        for (x, y) in [(0.0, 0.0), (79.0, 59.0), (12.3, 45.6)] {
            let p = cam.centre + cam.ray(x, y) * 2.5;
            let (u, v) = cam.project(&p).expect("in front");
            assert!(
                (u - x).abs() < 1e-9 && (v - y).abs() < 1e-9,
                "{u},{v} vs {x},{y}"
            );
        }
        // Positive yaw looks to the right (+x), positive pitch looks up (−y).
        let r = rotation(&[10.0, 0.0, 0.0]) * V3::z();
        assert!(r.x > 0.1);
        let r = rotation(&[0.0, 10.0, 0.0]) * V3::z();
        assert!(r.y < -0.1);
    }

    #[test]
    fn plane_hit_is_exact_and_step_face_found() {
        let plane = Shape::new(&Surface::Plane {
            distance: 2.0,
            tilt_deg: [10.0, 0.0],
        });
        let o = V3::zeros();
        let d = V3::new(0.2, -0.1, 1.0);
        let t = plane.intersect(&o, &d).expect("hits");
        let p = o + d * t;
        assert!((p.z - plane.height(p.x, p.y)).abs() < 1e-9);
        let n = plane.normal(&p);
        assert!((n.x - 10f64.to_radians().sin()).abs() < 1e-6 && n.z < 0.0);

        let step = Shape::new(&Surface::Step {
            distance: 2.0,
            depth: 0.5,
            edge_x: 0.1,
        });
        // A ray from the left aiming at the face between the two levels.
        let o = V3::new(-0.5, 0.0, 0.0);
        let target = V3::new(0.1, 0.0, 1.8);
        let t = step.intersect(&o, &(target - o)).expect("hits the face");
        let p = o + (target - o) * t;
        assert!((p.x - 0.1).abs() < 1e-6, "{p:?}");
        assert_eq!(step.normal(&p), V3::new(-1.0, 0.0, 0.0));
        // The far wall just left of the edge is hidden from a light on the right.
        assert!(!step.reaches(&V3::new(0.6, 0.0, 0.0), &V3::new(0.09, 0.0, 2.0)));
        assert!(step.reaches(&V3::new(-0.6, 0.0, 0.0), &V3::new(0.09, 0.0, 2.0)));
    }
}
