//! Detection timings (`deltaz bench-measure`): rendered dot grids measured by both centre
//! methods. Speed is reported, never asserted.

use super::detect::GrayView;
use super::render::{Background, Scene, Spot};
use super::{measure, CentreMethod, MeasureParams};
use std::time::Instant;

/// A grid of `cols × rows` dots of `radius` pixels filling a `width × height` image.
pub fn dot_grid(width: usize, height: usize, cols: usize, rows: usize, radius: f64) -> Scene {
    let (pc, pr) = (
        width as f64 / (cols as f64 + 1.0),
        height as f64 / (rows as f64 + 1.0),
    );
    let mut spots = Vec::with_capacity(cols * rows);
    for j in 1..=rows {
        for i in 1..=cols {
            // Sub-pixel phases spread over the grid.
            let phase = ((i * 7 + j * 13) % 10) as f64 / 10.0;
            spots.push(Spot::circle(
                i as f64 * pc + phase,
                j as f64 * pr + 0.7 * phase,
                radius,
                160.0,
            ));
        }
    }
    Scene {
        width,
        height,
        spots,
        background: Background {
            level: 40.0,
            slope_col: 10.0 / width as f64,
            slope_row: 0.0,
            ripple: 4.0,
            ripple_period: width as f64 / 3.0,
        },
        falloff: 0.2,
        blur_sigma: 1.0,
        noise_sigma: 2.0,
        seed: 11,
    }
}

/// Time `measure` on each case, best of `repeats`; one line per case and method.
pub fn run(repeats: usize) -> String {
    let cases = [
        ("768 x 512, 440 dots", dot_grid(768, 512, 22, 20, 4.0)),
        (
            "4000 x 3000 (12 MP), 4000 dots",
            dot_grid(4000, 3000, 80, 50, 6.0),
        ),
    ];
    let mut report = String::new();
    for (name, scene) in cases {
        let img = scene.render().to_u8();
        let view = GrayView {
            width: scene.width,
            height: scene.height,
            pixels: img.as_raw().as_slice(),
            dn: 1.0,
        };
        for method in [CentreMethod::Template, CentreMethod::Gravity] {
            let params = MeasureParams {
                method,
                ..MeasureParams::default()
            };
            let mut best = f64::INFINITY;
            let mut found = 0;
            for _ in 0..repeats.max(1) {
                let start = Instant::now();
                found = measure(&view, &params).targets.len();
                best = best.min(start.elapsed().as_secs_f64());
            }
            report.push_str(&format!(
                "{name}: {method:?}: {found} targets in {:.1} ms ({:.2} µs per target)\n",
                best * 1e3,
                best * 1e6 / found.max(1) as f64
            ));
        }
    }
    report.push_str(&identification());
    report
}

/// Time the epipolar identification of the paper's 440 dots on a plane 1740 mm away: building
/// the lookup (once per calibration) and identifying a frame.
fn identification() -> String {
    use crate::simulate::{images::true_rig, Scenario};
    use deltaz_shared::collinearity::{Camera, ExteriorOrientation};
    use deltaz_shared::identify::{Assignment, DepthRange, Identifier};
    use nalgebra::Vector3;
    let rig = true_rig(&Scenario::paper());
    let camera = Camera {
        grid: *rig.grid(),
        inner: *rig.inner(),
        exterior: ExteriorOrientation {
            kappa: 0.0,
            phi: 0.0,
            omega: 0.0,
            centre: Vector3::zeros(),
        },
    };
    let projector = rig.projector_centred();
    let dots: Vec<(f64, f64)> = projector
        .rays()
        .iter()
        .filter_map(|r| {
            let start = projector.centre() + r.offset;
            camera
                .world_to_pixel(&(start + r.direction * ((-1740.0 - start.z) / r.direction.z)))
                .ok()
        })
        .collect();
    let depth = DepthRange {
        near: 1680.0,
        far: 1800.0,
    };
    let start = Instant::now();
    let ident = Identifier::<f64, 512, 2048, 8192>::new(&rig, depth, 1.0, 16.0)
        .expect("the paper rig fits");
    let build = start.elapsed().as_secs_f64();
    let mut out = vec![Assignment::Unassigned; dots.len()];
    let rounds = 200;
    let start = Instant::now();
    let mut identified = 0;
    for _ in 0..rounds {
        identified = ident.identify_frame(&dots, &mut out);
    }
    let per_frame = start.elapsed().as_secs_f64() / f64::from(rounds);
    format!(
        "identification (paper rig, 1680-1800 mm, 1 px): lookup built in {:.2} ms ({} entries); {identified} of {} dots in {:.1} µs per frame ({:.2} µs per dot)\n",
        build * 1e3,
        ident.entries(),
        dots.len(),
        per_frame * 1e6,
        per_frame * 1e6 / dots.len() as f64
    )
}
