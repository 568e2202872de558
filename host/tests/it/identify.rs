//! Identification of projected dots on rendered frames of a curved (torso-like) surface, with the
//! paper's camera, projector centre and 20 × 22 pattern: render → measure → identify.

use deltaz_host::simulate::images::true_rig;
use deltaz_host::simulate::{true_camera, Scenario};
use deltaz_measure::detect::GrayView;
use deltaz_measure::render::{Background, Scene, Spot};
use deltaz_measure::{measure, MeasureParams};
use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
use deltaz_shared::identify::{Assignment, DepthRange, Identifier};
use deltaz_shared::projector::ProjectorRay;
use deltaz_shared::rig::Rig;
use nalgebra::{Vector2, Vector3};

/// Everything is in the camera system (camera at the origin, looking along −z).
struct Torso {
    /// Distance of the wall behind (mm).
    wall: f64,
    /// Height of the body above the wall (mm).
    height: f64,
    /// Half-width of the body across x (mm).
    half_width: f64,
    /// Centre of the body in x, y (mm).
    centre: (f64, f64),
}

impl Torso {
    /// Distance from the camera (−z) of the surface at (x, y): an elliptic cylinder along y
    /// whose ridge bends back towards the ends, standing on a wall.
    fn depth(&self, x: f64, y: f64) -> f64 {
        let u = (x - self.centre.0) / self.half_width;
        let v = (y - self.centre.1) / 600.0;
        let bulge = (1.0 - u * u).max(0.0).sqrt() * (1.0 - 0.5 * v * v).max(0.0);
        self.wall - self.height * bulge
    }

    /// Where the line start + t·dir meets the surface (bisection on t).
    fn hit(&self, start: Vector3<f64>, dir: Vector3<f64>) -> Vector3<f64> {
        let gap = |t: f64| {
            let p = start + dir * t;
            -p.z - self.depth(p.x, p.y)
        };
        let at_depth = |d: f64| (-d - start.z) / dir.z;
        let (mut lo, mut hi) = (
            at_depth(self.wall - self.height - 50.0),
            at_depth(self.wall + 50.0),
        );
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if gap(mid) < 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        start + dir * (0.5 * (lo + hi))
    }
}

type HostRig = Rig<f64, Vec<ProjectorRay<f64>>>;

/// One frame: the paper rig seeing a torso; the true dots (id, pixel) and the rendered scene.
fn frame(torso: &Torso, dot_angle: f64, seed: u64) -> (HostRig, Vec<(u16, Vector2<f64>)>, Scene) {
    let scenario = Scenario::paper();
    let (grid, inner) = true_camera(&scenario);
    let camera = Camera {
        grid,
        inner,
        exterior: ExteriorOrientation {
            kappa: 0.0,
            phi: 0.0,
            omega: 0.0,
            centre: Vector3::zeros(),
        },
    };
    let rig = true_rig(&scenario);
    let centre = rig.projector_centred().centre();
    let rays = rig.projector_centred().rays().to_vec();
    let mut dots = Vec::new();
    let mut spots = Vec::new();
    for ray in &rays {
        let start = centre + ray.offset;
        let hit = torso.hit(start, ray.direction);
        let Ok((col, row)) = camera.world_to_pixel(&hit) else {
            continue;
        };
        if !grid.contains(col, row) {
            continue;
        }
        // The dot's footprint: rays at the dot's angular radius around it, imaged.
        let e1 = ray.direction.cross(&Vector3::y()).normalize();
        let e2 = ray.direction.cross(&e1);
        let edge = |e: Vector3<f64>| {
            let (c, r) = camera
                .world_to_pixel(&torso.hit(start, (ray.direction + e * dot_angle).normalize()))
                .unwrap();
            Vector2::new(c - col, r - row)
        };
        let (a1, a2) = (edge(e1), edge(e2));
        let svd = nalgebra::Matrix2::from_columns(&[a1, a2]).svd(true, false);
        let u = svd.u.unwrap();
        spots.push(Spot {
            col,
            row,
            semi_a: svd.singular_values[0],
            semi_b: svd.singular_values[1],
            angle: u[(1, 0)].atan2(u[(0, 0)]),
            amplitude: 170.0,
        });
        dots.push((ray.id, Vector2::new(col, row)));
    }
    let scene = Scene {
        width: grid.width as usize,
        height: grid.height as usize,
        spots,
        background: Background {
            level: 35.0,
            slope_col: 0.03,
            slope_row: 0.02,
            ripple: 5.0,
            ripple_period: 200.0,
        },
        falloff: 0.3,
        blur_sigma: 1.0,
        noise_sigma: 2.0,
        seed,
    };
    (rig, dots, scene)
}

type Paper = Identifier<f64, 512, 2048, 8192>;
/// The device's identifier, as the firmware declares it (f32, its capacities).
type Device = deltaz_firmware::device::DeviceIdentifier;

/// The rig in f32 as the device holds it (centred on the camera, cast from the host's f64).
fn device_rig(rig: &HostRig) -> Rig<f32, Vec<ProjectorRay<f32>>> {
    rig.cast().unwrap()
}

/// The bar: no wrong assignment, every other dot reported, ≥ 99 % identified.
#[test]
fn torso_frames_identified() {
    let torsos = [
        Torso {
            wall: 1740.0,
            height: 110.0,
            half_width: 260.0,
            centre: (-40.0, 30.0),
        },
        Torso {
            wall: 1700.0,
            height: 90.0,
            half_width: 320.0,
            centre: (60.0, -20.0),
        },
    ];
    for (n, torso) in torsos.iter().enumerate() {
        let (rig, truth, scene) = frame(torso, 0.0035, 40 + n as u64);
        let depth = DepthRange {
            near: torso.wall - torso.height - 20.0,
            far: torso.wall + 20.0,
        };
        let ident = Paper::new(&rig, depth, 1.0, 16.0).unwrap();
        let img = scene.render().to_u8();
        let view = GrayView {
            width: scene.width,
            height: scene.height,
            pixels: img.as_raw().as_slice(),
            dn: 1.0,
        };
        let measured = measure(&view, &MeasureParams::default());
        let dots: Vec<(f64, f64)> = measured.targets.iter().map(|t| (t.col, t.row)).collect();
        let mut out = vec![Assignment::Unassigned; dots.len()];
        let identified = ident.identify_frame(&dots, &mut out);
        let (mut wrong, mut unassigned, mut ambiguous, mut conflicts) = (0, 0, 0, 0);
        let mut sum2 = 0.0;
        for (dot, a) in dots.iter().zip(&out) {
            let (true_id, miss) = truth
                .iter()
                .map(|(id, p)| (*id, (p - Vector2::new(dot.0, dot.1)).norm()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(miss < 0.3, "measured dot {dot:?} is no true dot");
            sum2 += miss * miss;
            match a {
                Assignment::Ray { id, .. } if *id != true_id => wrong += 1,
                Assignment::Ray { .. } => {}
                Assignment::Ambiguous { .. } => ambiguous += 1,
                Assignment::Conflict { .. } => conflicts += 1,
                Assignment::Unassigned => unassigned += 1,
            }
        }
        let rate = identified as f64 / truth.len() as f64;
        println!(
            "torso {n}: {} dots in view, {} measured, {identified} identified ({:.2} %), centre RMS {:.4} px, {ambiguous} ambiguous, {conflicts} conflicts, {unassigned} unassigned, {wrong} wrong; close pairs {}, grid entries {}",
            truth.len(),
            dots.len(),
            100.0 * rate,
            (sum2 / dots.len() as f64).sqrt(),
            ident.close_pairs(),
            ident.entries()
        );
        assert_eq!(wrong, 0);
        // The device (f32, the same shared code) makes the same assignments.
        let device = std::thread::scope(|s| {
            std::thread::Builder::new()
                .stack_size(16 << 20)
                .spawn_scoped(s, || {
                    Box::new(
                        Device::new(
                            &device_rig(&rig),
                            DepthRange {
                                near: depth.near as f32,
                                far: depth.far as f32,
                            },
                            1.0,
                            16.0,
                        )
                        .unwrap(),
                    )
                })
                .unwrap()
                .join()
                .unwrap()
        });
        let dots32: Vec<(f32, f32)> = dots.iter().map(|&(c, r)| (c as f32, r as f32)).collect();
        let mut out32 = vec![Assignment::Unassigned; dots.len()];
        assert_eq!(device.identify_frame(&dots32, &mut out32), identified);
        for (a, b) in out.iter().zip(&out32) {
            assert_eq!(a.id(), b.id());
        }
        if n == 0 {
            println!(
                "device identifier: {} bytes (f32, {} rays, {} cells, {} entries), cells of {} px",
                std::mem::size_of::<Device>(),
                deltaz_firmware::device::MAX_RAYS,
                deltaz_firmware::device::IDENTIFIER_CELLS,
                deltaz_firmware::device::IDENTIFIER_ENTRIES,
                device.cell()
            );
        }
        assert!(
            truth.len() > 400,
            "the pattern should fill the frame: {}",
            truth.len()
        );
        assert!(rate >= 0.99, "identified {:.2} %", 100.0 * rate);
    }
}
