//! A parametric scoliotic back with its truth, pure geometry (mm, rad).
//!
//! The trunk has its own frame: `a` across (the subject's right is +a), `v` along the trunk's
//! axis from the pelvis (v = 0) to the vertebra prominens (v = [`Trunk::length`]), `n` out of
//! the back. Each section v = const is a symmetric profile `h(s)` (an elliptic trunk, the
//! paraspinal muscles either side of the spinous groove, the scapulae), rotated by the
//! scoliotic rotation θ(v) about the vertebral axis [`Trunk::axis_depth`] below the midline and
//! shifted by the lateral deviation u(v) of the spine and the sagittal profile (kyphosis and
//! lordosis standing, an arch bent forward). Standing, arms hang beside the trunk.
//!
//! The trunk is placed in the camera system (x right, y up, z toward the camera, the camera at
//! the origin): standing with v along +y and n along +z, bent forward (Adams) with v along −x
//! (the head at −x) and the back up toward the camera; a [`Pose`] sways it about its centre.
//!
//! The truth ([`BackModel::symmetry_point`], [`BackModel::rotation`], [`BackModel::skin_angle`],
//! [`BackModel::scoliometer`], [`BackModel::depth`]) is computed from the placed surface itself
//! in any analysis frame ([`Axes`]): the symmetry point of a level is where the spine's surface
//! line (the rotated midline) crosses it (each section is mirror symmetric about it), the
//! surface rotation atan(∂n/∂a) there, a skin angle from two surface points, the scoliometer's
//! bitangent from the exact section.

use deltaz_surface::scoliometer::resting_slope;
use nalgebra::{Rotation3, Vector3};
use std::f64::consts::FRAC_PI_2;

/// The body's shape (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trunk {
    /// From the pelvis (v = 0) to the vertebra prominens.
    pub length: f64,
    /// Half-widths at the hips (v = 0), the waist (0.4 length) and the shoulders (0.85 length).
    pub half_width: [f64; 3],
    /// Half-width of the neck above the shoulders.
    pub neck: f64,
    /// Depth of the elliptic section (the trunk's front-back half-depth).
    pub depth: f64,
    /// Height of the paraspinal muscles.
    pub paraspinal: f64,
    /// Their distance from the midline.
    pub paraspinal_offset: f64,
    /// Their width (Gaussian σ).
    pub paraspinal_width: f64,
    /// Depth of the spinous groove.
    pub groove: f64,
    /// Its width (Gaussian σ).
    pub groove_width: f64,
    /// Height of the scapulae.
    pub scapula: f64,
    /// Their distance from the midline.
    pub scapula_offset: f64,
    /// Amplitude of the thoracic kyphosis (standing).
    pub kyphosis: f64,
    /// Amplitude of the lumbar lordosis (standing).
    pub lordosis: f64,
    /// Depth of the vertebral axis the sections rotate about, below the midline.
    pub axis_depth: f64,
    /// Radius of the arms (standing); 0 for none.
    pub arm_radius: f64,
    /// Gap between the arms and the shoulders' outline.
    pub arm_gap: f64,
}

impl Default for Trunk {
    fn default() -> Self {
        Self {
            length: 480.0,
            half_width: [165.0, 148.0, 185.0],
            neck: 55.0,
            depth: 95.0,
            paraspinal: 6.0,
            paraspinal_offset: 32.0,
            paraspinal_width: 16.0,
            groove: 3.0,
            groove_width: 12.0,
            scapula: 7.0,
            scapula_offset: 90.0,
            kyphosis: 20.0,
            lordosis: 12.0,
            axis_depth: 60.0,
            arm_radius: 42.0,
            arm_gap: 12.0,
        }
    }
}

/// One scoliotic curve: a Gaussian bump of rotation and lateral shift along the spine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Curve {
    /// Its apex (fraction of the trunk length from the pelvis).
    pub apex: f64,
    /// Its extent (Gaussian σ, fraction of the length).
    pub extent: f64,
    /// Rotation at the apex (rad; positive brings the +a side toward the camera).
    pub rotation: f64,
    /// Lateral shift of the spine at the apex (mm, +a).
    pub shift: f64,
}

/// A spinal deformity: its curves (none for a straight back).
#[derive(Debug, Clone, PartialEq)]
pub struct Deformity {
    /// Its name.
    pub name: &'static str,
    /// The curves.
    pub curves: Vec<Curve>,
}

impl Deformity {
    /// A straight back.
    pub fn straight() -> Self {
        Self {
            name: "straight",
            curves: vec![],
        }
    }

    /// A right thoracic curve (apex mid-thoracic, 10° of surface rotation, 18 mm shift).
    pub fn thoracic() -> Self {
        Self {
            name: "thoracic",
            curves: vec![curve(0.62, 0.15, 10.0, 18.0)],
        }
    }

    /// A left lumbar curve.
    pub fn lumbar() -> Self {
        Self {
            name: "lumbar",
            curves: vec![curve(0.25, 0.12, -7.0, -12.0)],
        }
    }

    /// A double major curve: right thoracic, left lumbar.
    pub fn double() -> Self {
        Self {
            name: "double",
            curves: vec![curve(0.65, 0.12, 8.0, 12.0), curve(0.25, 0.11, -6.0, -10.0)],
        }
    }

    /// A severe right thoracic curve (16° of surface rotation, 30 mm shift).
    pub fn severe() -> Self {
        Self {
            name: "severe",
            curves: vec![curve(0.6, 0.16, 16.0, 30.0)],
        }
    }

    /// The five deformities above.
    pub fn all() -> Vec<Self> {
        vec![
            Self::straight(),
            Self::thoracic(),
            Self::lumbar(),
            Self::double(),
            Self::severe(),
        ]
    }

    /// The deformity of [`Deformity::all`] called `name`.
    pub fn named(name: &str) -> Option<Self> {
        Self::all().into_iter().find(|d| d.name == name)
    }
}

fn curve(apex: f64, extent: f64, rotation_deg: f64, shift: f64) -> Curve {
    Curve {
        apex,
        extent,
        rotation: rotation_deg.to_radians(),
        shift,
    }
}

/// How the subject stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Posture {
    /// Upright, back to the camera.
    Standing,
    /// Bent forward (Adams), the trunk across the image, the head at −x.
    ForwardBent,
}

/// A sway of the whole trunk about its centre: a rotation (axis × angle, rad) then a
/// translation (mm), in the camera system.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose {
    /// Rotation vector (rad).
    pub rotation: Vector3<f64>,
    /// Translation (mm).
    pub translation: Vector3<f64>,
}

/// What a camera ray meets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// The back.
    Back,
    /// An arm.
    Arm,
    /// The wall behind the subject ([`BackModel::backdrop`]).
    Backdrop,
}

/// A surface point with its outward unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The point (camera system).
    pub point: Vector3<f64>,
    /// The surface's unit normal there, out of the body.
    pub normal: Vector3<f64>,
    /// What was met.
    pub part: Part,
}

/// An analysis frame in the camera system: orthonormal `across` × `axis` = `up`; a point X has
/// the coordinates (across·X, axis·X, up·X) = (a, v, n).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axes {
    /// Across the trunk.
    pub across: Vector3<f64>,
    /// Along the trunk's axis (the levels).
    pub axis: Vector3<f64>,
    /// Toward the camera (the depth).
    pub up: Vector3<f64>,
}

impl Axes {
    /// The camera's own axes (x, y, z): a standing back with vertical +y.
    pub fn camera() -> Self {
        Self {
            across: Vector3::x(),
            axis: Vector3::y(),
            up: Vector3::z(),
        }
    }

    fn point(&self, a: f64, v: f64, n: f64) -> Vector3<f64> {
        self.across * a + self.axis * v + self.up * n
    }
}

/// A back in the camera's view.
#[derive(Debug, Clone, PartialEq)]
pub struct BackModel {
    /// The body.
    pub trunk: Trunk,
    /// The deformity.
    pub deformity: Deformity,
    /// Standing or bent forward.
    pub posture: Posture,
    /// Distance of the back's centre from the camera (mm).
    pub distance: f64,
    /// The sway of this frame.
    pub pose: Pose,
    /// A wall behind the subject, square to the camera's axis this far from it (mm), or none.
    pub backdrop: Option<f64>,
}

/// Cuts the section at this fraction of its half-width, where it turns away (about 67° steep).
const EDGE: f64 = 0.97;
/// The spine's surface line ends this far below the pelvis level and above the prominens (mm).
const BELOW: f64 = 40.0;
const NECK: f64 = 70.0;

/// A section's level v and what its points share: the half-width, the depth, the shoulder
/// blades' height, the scoliotic rotation's sine and cosine, the shift, the sagittal height.
struct Level {
    v: f64,
    half_width: f64,
    depth: f64,
    shoulder_blades: f64,
    sin: f64,
    cos: f64,
    shift: f64,
    sagittal: f64,
}

fn gauss(x: f64, sigma: f64) -> f64 {
    (-0.5 * (x / sigma).powi(2)).exp()
}

fn smoothstep(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl BackModel {
    /// A back standing 1.5 m from the camera, without sway.
    pub fn standing(deformity: Deformity) -> Self {
        Self {
            trunk: Trunk::default(),
            deformity,
            posture: Posture::Standing,
            distance: 1500.0,
            pose: Pose::default(),
            backdrop: None,
        }
    }

    /// The same back bent forward (Adams).
    pub fn forward_bent(deformity: Deformity) -> Self {
        Self {
            posture: Posture::ForwardBent,
            ..Self::standing(deformity)
        }
    }

    /// This model swayed by `pose`.
    pub fn with_pose(&self, pose: Pose) -> Self {
        Self {
            pose,
            ..self.clone()
        }
    }

    /// Scoliotic rotation θ(v) (rad).
    pub fn theta(&self, v: f64) -> f64 {
        self.along(v, |c| c.rotation)
    }

    /// Lateral shift u(v) of the spine (mm).
    pub fn shift(&self, v: f64) -> f64 {
        self.along(v, |c| c.shift)
    }

    fn along(&self, v: f64, amplitude: impl Fn(&Curve) -> f64) -> f64 {
        let f = v / self.trunk.length;
        let curves = self.deformity.curves.iter();
        curves
            .map(|c| amplitude(c) * gauss(f - c.apex, c.extent))
            .sum()
    }

    /// Half-width of the section at v.
    fn half_width(&self, v: f64) -> f64 {
        let t = &self.trunk;
        let [hips, waist, shoulders] = t.half_width;
        let f = v / t.length;
        if f < 0.4 {
            waist + (hips - waist) * (1.0 - f.max(0.0) / 0.4).powi(2)
        } else if f < 0.9 {
            waist + (shoulders - waist) * smoothstep((f - 0.4) / 0.45)
        } else {
            shoulders - (shoulders - t.neck) * smoothstep((f - 0.9) / 0.1)
        }
    }

    /// The sagittal profile: the midline's height at v (before rotation).
    fn sagittal(&self, v: f64) -> f64 {
        let t = &self.trunk;
        let f = v / t.length;
        match self.posture {
            Posture::Standing => {
                t.kyphosis * gauss(f - 0.68, 0.16) - t.lordosis * gauss(f - 0.2, 0.1)
            }
            Posture::ForwardBent => 70.0 * (1.0 - ((f - 0.55) / 0.6).powi(2)) - 60.0 * f,
        }
    }

    /// What the section at level v is made of, worked out once for all its points.
    fn level(&self, v: f64) -> Level {
        let t = &self.trunk;
        let half_width = self.half_width(v);
        let (sin, cos) = self.theta(v).sin_cos();
        Level {
            v,
            half_width,
            depth: t.depth * (half_width / t.half_width[2]).sqrt(),
            shoulder_blades: t.scapula * gauss(v / t.length - 0.76, 0.09),
            sin,
            cos,
            shift: self.shift(v),
            sagittal: self.sagittal(v),
        }
    }

    /// The symmetric section profile h(s) at its level and its slope dh/ds.
    fn profile(&self, l: &Level, s: f64) -> (f64, f64) {
        let t = &self.trunk;
        let (w, depth) = (l.half_width, l.depth);
        let q = (s / w).clamp(-EDGE, EDGE);
        let root = (1.0 - q * q).sqrt();
        let mut h = depth * (root - 1.0);
        let mut dh = -depth * q / (root * w);
        let bumps = [
            (t.paraspinal, t.paraspinal_offset, t.paraspinal_width),
            (l.shoulder_blades, t.scapula_offset, 30.0),
        ];
        for (height, offset, width) in bumps {
            for side in [-1.0, 1.0] {
                let d = s - side * offset;
                let g = height * gauss(d, width);
                h += g;
                dh -= g * d / (width * width);
            }
        }
        let g = t.groove * gauss(s, t.groove_width);
        h -= g;
        dh += g * s / (t.groove_width * t.groove_width);
        (h, dh)
    }

    /// The section's point at s in the trunk frame (a, n) and d(a, n)/ds.
    fn section(&self, l: &Level, s: f64) -> ((f64, f64), (f64, f64)) {
        let (h, dh) = self.profile(l, s);
        let (sin, cos) = (l.sin, l.cos);
        let r = self.trunk.axis_depth;
        let a = l.shift + s * cos - (h + r) * sin;
        let n = l.sagittal - r + s * sin + (h + r) * cos;
        ((a, n), (cos - dh * sin, sin + dh * cos))
    }

    /// A height n above every point of the section at its level (its bumps taken at their
    /// full height on both sides, its turn at its widest; a micrometre to spare for rounding):
    /// a ray there is clear of the back.
    fn highest(&self, l: &Level) -> f64 {
        let t = &self.trunk;
        let r = t.axis_depth;
        if l.cos < 0.0 {
            return f64::INFINITY;
        }
        let bumps = 2.0 * (t.paraspinal.max(0.0) + l.shoulder_blades.max(0.0));
        let h = bumps + (-t.groove).max(0.0) + (-l.depth).max(0.0);
        l.sagittal - r + EDGE * l.half_width * l.sin.abs() + (h + r) * l.cos + 1e-3
    }

    /// Whether the trunk's surface holds the section point s at its level.
    fn on_trunk(&self, l: &Level, s: f64) -> bool {
        let top = if s.abs() <= self.trunk.neck {
            self.trunk.length + NECK
        } else {
            self.trunk.length
        };
        l.v >= -BELOW && l.v <= top && s.abs() <= EDGE * l.half_width
    }

    /// The back's height n at (a, v) in the trunk frame (None off the back).
    fn trunk_height(&self, a: f64, v: f64) -> Option<f64> {
        self.height_on(&self.level(v), a)
    }

    /// The back's height n at a on the section at its level (None off the back).
    fn height_on(&self, l: &Level, a: f64) -> Option<f64> {
        let mut s = (a - l.shift) / l.cos;
        for _ in 0..30 {
            let ((sa, _), (da, _)) = self.section(l, s);
            let step = (sa - a) / da;
            s -= step;
            if step.abs() < 1e-10 {
                break;
            }
        }
        let ((sa, n), _) = self.section(l, s);
        ((sa - a).abs() < 1e-6 && self.on_trunk(l, s)).then_some(n)
    }

    /// The placement: camera point = R (trunk point − centre) + (0, 0, −distance) + t.
    fn placement(&self) -> (Rotation3<f64>, Vector3<f64>, Vector3<f64>) {
        let posture = match self.posture {
            Posture::Standing => Rotation3::identity(),
            Posture::ForwardBent => Rotation3::from_axis_angle(&Vector3::z_axis(), FRAC_PI_2),
        };
        let r = Rotation3::new(self.pose.rotation) * posture;
        let centre = Vector3::new(0.0, self.trunk.length / 2.0, 0.0);
        let offset = Vector3::new(0.0, 0.0, -self.distance) + self.pose.translation;
        (r, centre, offset)
    }

    fn to_camera(&self, p: Vector3<f64>) -> Vector3<f64> {
        let (r, centre, offset) = self.placement();
        r * (p - centre) + offset
    }

    fn to_trunk(&self, x: Vector3<f64>) -> Vector3<f64> {
        let (r, centre, offset) = self.placement();
        r.inverse() * (x - offset) + centre
    }

    /// The arms' axes (a, n) in the trunk frame and their extent in v (standing only).
    fn arms(&self) -> Vec<(f64, f64)> {
        let t = &self.trunk;
        if self.posture != Posture::Standing || t.arm_radius <= 0.0 {
            return vec![];
        }
        let a = t.half_width[2] + t.arm_gap + t.arm_radius;
        let n = -0.6 * t.depth;
        vec![(-a, n), (a, n)]
    }

    /// Where the ray `origin + t dir` (t > 0) first meets the body, or past it the backdrop.
    pub fn hit(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let backdrop = self.backdrop.and_then(|distance| {
            let t = (-distance - origin.z) / dir.z;
            (t > 0.0 && t.is_finite()).then(|| Hit {
                point: origin + dir * t,
                normal: Vector3::z(),
                part: Part::Backdrop,
            })
        });
        let beyond = |h: &Hit| (h.point - origin).dot(dir);
        match (self.hit_body(origin, dir), backdrop) {
            (Some(body), Some(wall)) if beyond(&wall) < beyond(&body) => Some(wall),
            (None, wall) => wall,
            (body, _) => body,
        }
    }

    /// Where the ray `origin + t dir` (t > 0) first meets the body.
    fn hit_body(&self, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let (o, d) = (self.to_trunk(*origin), {
            let (r, _, _) = self.placement();
            r.inverse() * dir.normalize()
        });
        let back = self.hit_back(&o, &d);
        let arms = self
            .arms()
            .into_iter()
            .filter_map(|axis| self.hit_arm(&o, &d, axis));
        let (_, p, normal, part) = back
            .into_iter()
            .chain(arms)
            .min_by(|x, y| x.0.total_cmp(&y.0))?;
        let (r, _, _) = self.placement();
        Some(Hit {
            point: self.to_camera(p),
            normal: r * normal,
            part,
        })
    }

    /// The first crossing of the back along a trunk-frame ray: march, then bisect.
    #[allow(clippy::type_complexity)]
    fn hit_back(
        &self,
        o: &Vector3<f64>,
        d: &Vector3<f64>,
    ) -> Option<(f64, Vector3<f64>, Vector3<f64>, Part)> {
        if d.z >= 0.0 {
            return None;
        }
        let top = 2.0 * self.trunk.kyphosis + 120.0;
        let t0 = ((top - o.z) / d.z).max(0.0);
        // The ray's point at t, its level, and its height above the back there.
        let at = |t: f64| {
            let p = o + d * t;
            (p, self.level(p.y))
        };
        let over = |p: Vector3<f64>, l: &Level| self.height_on(l, p.x).map(|h| p.z - h);
        let above = |t: f64| {
            let (p, l) = at(t);
            over(p, &l)
        };
        // The ray's height above the back at t, where it is not above the highest point of its
        // level's section (there: None, without solving for the back's height).
        let near = |t: f64| {
            let (p, l) = at(t);
            (p.z <= self.highest(&l)).then(|| over(p, &l))
        };
        let step = 2.0;
        let mut prev: Option<(f64, f64)> = None;
        // The last step, when the march passed it clear of the back without looking closer:
        // the step before a crossing is looked at (the same steps, the same crossing).
        let mut passed: Option<f64> = None;
        let mut t = t0;
        while t < t0 + 2.0 * (top + self.trunk.depth + 100.0) / -d.z {
            let Some(here) = near(t) else {
                passed = Some(t);
                t += step;
                continue;
            };
            if let Some(tp) = passed.take() {
                prev = above(tp).map(|f| (tp, f));
            }
            match (here, prev) {
                (Some(f), Some((tp, fp))) if f <= 0.0 && fp > 0.0 => {
                    // Bisected until no number lies between (about 43 halvings of 2 mm at
                    // 1500 mm).
                    let (mut lo, mut hi) = (tp, t);
                    for _ in 0..60 {
                        let mid = 0.5 * (lo + hi);
                        if mid == lo || mid == hi {
                            break;
                        }
                        match above(mid) {
                            Some(f) if f <= 0.0 => hi = mid,
                            _ => lo = mid,
                        }
                    }
                    let p = o + d * hi;
                    return Some((hi, p, self.trunk_normal(p.x, p.y)?, Part::Back));
                }
                (f, _) => prev = f.map(|f| (t, f)),
            }
            t += step;
        }
        None
    }

    fn trunk_normal(&self, a: f64, v: f64) -> Option<Vector3<f64>> {
        let e = 0.01;
        let da = self.trunk_height(a + e, v)? - self.trunk_height(a - e, v)?;
        let dv = self.trunk_height(a, v + e)? - self.trunk_height(a, v - e)?;
        Some(Vector3::new(-da / (2.0 * e), -dv / (2.0 * e), 1.0).normalize())
    }

    #[allow(clippy::type_complexity)]
    fn hit_arm(
        &self,
        o: &Vector3<f64>,
        d: &Vector3<f64>,
        (a, n): (f64, f64),
    ) -> Option<(f64, Vector3<f64>, Vector3<f64>, Part)> {
        let r = self.trunk.arm_radius;
        let (px, pz) = (o.x - a, o.z - n);
        let qa = d.x * d.x + d.z * d.z;
        let qb = px * d.x + pz * d.z;
        let disc = qb * qb - qa * (px * px + pz * pz - r * r);
        let t = (-qb - disc.max(0.0).sqrt()) / qa;
        let p = o + d * t;
        let length = self.trunk.length;
        (disc > 0.0 && t > 0.0 && p.y > 0.1 * length && p.y < 0.85 * length).then(|| {
            let normal = Vector3::new(p.x - a, 0.0, p.z - n) / r;
            (t, p, normal, Part::Arm)
        })
    }

    /// The exact surface's depth n at (a, v) of `axes` (the first surface met coming from the
    /// camera's side along −up); None off the body.
    pub fn depth(&self, axes: &Axes, a: f64, v: f64) -> Option<f64> {
        let start = axes.point(
            a,
            v,
            axes.up.dot(&Vector3::new(0.0, 0.0, -self.distance)) + 600.0,
        );
        let hit = self.hit(&start, &-axes.up)?;
        Some(axes.up.dot(&hit.point))
    }

    /// The spine's surface point at trunk level v, in the camera system.
    fn spine(&self, v: f64) -> Vector3<f64> {
        let ((a, n), _) = self.section(&self.level(v), 0.0);
        self.to_camera(Vector3::new(a, v, n))
    }

    /// The true symmetry point (a, n) at level `v` of `axes`: where the spine's surface line
    /// crosses the level (None beyond its ends).
    pub fn symmetry_point(&self, axes: &Axes, v: f64) -> Option<(f64, f64)> {
        let level = |w: f64| axes.axis.dot(&self.spine(w)) - v;
        let (mut lo, mut hi) = (-BELOW, self.trunk.length + NECK);
        if level(lo) * level(hi) > 0.0 {
            return None;
        }
        if level(lo) > 0.0 {
            std::mem::swap(&mut lo, &mut hi);
        }
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if level(mid) > 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        let p = self.spine(0.5 * (lo + hi));
        Some((axes.across.dot(&p), axes.up.dot(&p)))
    }

    /// The true surface rotation at level v: atan(∂n/∂a) at the symmetry point (rad).
    pub fn rotation(&self, axes: &Axes, v: f64) -> Option<f64> {
        let (a, _) = self.symmetry_point(axes, v)?;
        let e = 0.25;
        let slope = (self.depth(axes, a + e, v)? - self.depth(axes, a - e, v)?) / (2.0 * e);
        Some(slope.atan())
    }

    /// The true sagittal slope at level v: atan(∂n/∂v) at the symmetry point (rad).
    pub fn sagittal_slope(&self, axes: &Axes, v: f64) -> Option<f64> {
        let (a, _) = self.symmetry_point(axes, v)?;
        let e = 0.25;
        let slope = (self.depth(axes, a, v + e)? - self.depth(axes, a, v - e)?) / (2.0 * e);
        Some(slope.atan())
    }

    /// The true skin angle at level v: of the line through the surface points `distance` either
    /// side of the symmetry point (rad, positive when the +a side is nearer the camera).
    pub fn skin_angle(&self, axes: &Axes, v: f64, distance: f64) -> Option<f64> {
        let (a, _) = self.symmetry_point(axes, v)?;
        let rise = self.depth(axes, a + distance, v)? - self.depth(axes, a - distance, v)?;
        Some((rise / (2.0 * distance)).atan())
    }

    /// The true scoliometer reading at level v: the angle (rad) of the line resting on the
    /// section over `window` (a from, a to) across the symmetry point: of all lines above the
    /// section, the lowest over the symmetry point.
    pub fn scoliometer(&self, axes: &Axes, v: f64, window: (f64, f64)) -> Option<f64> {
        let (centre, _) = self.symmetry_point(axes, v)?;
        let count = ((window.1 - window.0) / 0.5).ceil() as usize;
        let section: Vec<(f64, f64)> = (0..=count)
            .map(|k| window.0 + (window.1 - window.0) * k as f64 / count as f64)
            .map(|a| self.depth(axes, a, v).map(|n| (a, n)))
            .collect::<Option<_>>()?;
        Some(resting_slope(&section, centre).atan())
    }
}

/// A projector beside the camera casting a square lattice of rays on the back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lattice {
    /// The projector's centre (camera system).
    pub projector: Vector3<f64>,
    /// Spacing of the dots on a plane `distance` in front of the camera (mm).
    pub spacing: f64,
    /// That plane's distance.
    pub distance: f64,
    /// Half-extent of the lattice on that plane (x, y, mm).
    pub extent: [f64; 2],
    /// Dots whose camera or projector ray meets the surface more obliquely are not seen (rad
    /// from the normal).
    pub max_incidence: f64,
}

impl Lattice {
    /// A projector 250 mm right of the camera, dots `spacing` apart at 1.5 m over 900 × 900 mm.
    pub fn beside_camera(spacing: f64) -> Self {
        Self {
            projector: Vector3::new(250.0, 0.0, 0.0),
            spacing,
            distance: 1500.0,
            extent: [450.0, 450.0],
            max_incidence: 80f64.to_radians(),
        }
    }
}

/// A dot of the lattice on the body: its ray (column, row of the lattice) and its true point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatticeDot {
    /// The lattice node of its ray.
    pub ray: [i32; 2],
    /// What it lies on, with the normal.
    pub hit: Hit,
}

impl BackModel {
    /// The dots of `lattice` the camera (at the origin) sees on this body: each ray's first hit,
    /// kept when the camera's line of sight reaches the same point and neither ray grazes it.
    pub fn sample(&self, lattice: &Lattice) -> Vec<LatticeDot> {
        let [ni, nj] = lattice.extent.map(|e| (e / lattice.spacing).floor() as i32);
        let mut dots = Vec::new();
        for j in -nj..=nj {
            for i in -ni..=ni {
                let target = Vector3::new(
                    f64::from(i) * lattice.spacing,
                    f64::from(j) * lattice.spacing,
                    -lattice.distance,
                );
                let dir = (target - lattice.projector).normalize();
                let Some(hit) = self.hit(&lattice.projector, &dir) else {
                    continue;
                };
                let sight = hit.point.normalize();
                let seen = self.hit(&Vector3::zeros(), &sight);
                let visible = seen.is_some_and(|s| (s.point - hit.point).norm() < 0.5);
                let cos_min = lattice.max_incidence.cos();
                let lit = -hit.normal.dot(&dir) > cos_min;
                let faced = -hit.normal.dot(&sight) > cos_min;
                if visible && lit && faced {
                    dots.push(LatticeDot { ray: [i, j], hit });
                }
            }
        }
        dots
    }
}
