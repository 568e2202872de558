//! Field → camera: observations and control mapped to the self-calibrating bundle adjustment of
//! [`deltaz_calib::bundle`], and the result as `camera.json` with every observation's residual.

use crate::io::camera_file::{
    CameraFile, Correlation, InnerCovariance, InnerParams, PoseParams, Rejected, Station,
    CAMERA_FORMAT,
};
use crate::io::control::ControlPoint;
use crate::io::observations::{Observation, PointKind};
use crate::io::FileError;
use crate::report::calibration_plots::{residual_plots, Plot};
use crate::report::plots::write_with_plots;
use crate::report::residuals;
use deltaz_calib::bundle::problem::Problem;
use deltaz_calib::bundle::{BuildError, Calibration, CalibrationOptions};
use deltaz_calib::input::Measurement;
use deltaz_calib::residual::image_residual;
use deltaz_calib::system_adjustment::CameraPrior;
use deltaz_shared::camera::{InnerOrientation, PixelGrid};
use std::path::Path;

pub use deltaz_calib::bundle::calibrate;

/// Target observations of a set of images and the control they refer to, with the file (or
/// folder) they came from for error messages.
#[derive(Debug, Clone, Copy)]
pub struct Targets<'a> {
    /// Where the observations came from.
    pub path: &'a Path,
    /// The observations (their `control` rows are the targets).
    pub observations: &'a [Observation],
    /// The control points (mm, with σ); empty for a free network.
    pub control: &'a [ControlPoint],
}

/// The field's self-calibrating bundle adjustment: the problem built from `field`'s targets
/// ([`build_problem`]) and adjusted from `start`.
pub fn bundle_field(
    grid: &PixelGrid<f64>,
    start: &InnerOrientation<f64>,
    field: Targets,
    options: &CalibrationOptions,
) -> anyhow::Result<Calibration> {
    let problem = build_problem(
        field.path,
        grid,
        start,
        field.observations,
        field.control,
        options,
    )?;
    calibrate(problem, options)
        .map_err(|e| anyhow::anyhow!("{}: bundle adjustment: {e}", field.path.display()))
}

/// Builds the bundle problem from an observation file's contents (its targets; dots are left
/// out): errors name `obs_path` and, where one observation is at fault, its line. The problem's
/// `source` indices refer to `observations`.
pub fn build_problem(
    obs_path: &Path,
    grid: &PixelGrid<f64>,
    inner: &InnerOrientation<f64>,
    observations: &[Observation],
    control: &[ControlPoint],
    options: &CalibrationOptions,
) -> anyhow::Result<Problem> {
    let (sources, measurements): (Vec<usize>, Vec<Measurement>) = observations
        .iter()
        .enumerate()
        .filter(|(_, o)| o.kind == PointKind::Control)
        .map(|(n, o)| {
            let m = Measurement {
                image: o.image.clone(),
                point: o.point.clone(),
                col: o.col,
                row: o.row,
            };
            (n, m)
        })
        .unzip();
    let mut problem =
        deltaz_calib::bundle::build_problem(grid, inner, &measurements, control, options).map_err(
            |e| match &e {
                BuildError::UnknownPoint { measurement, .. } => FileError::at(
                    obs_path,
                    observations[sources[*measurement]].line,
                    e.to_string(),
                ),
                _ => FileError::whole(obs_path, e.to_string()),
            },
        )?;
    for o in &mut problem.observations {
        o.source = sources[o.source];
    }
    Ok(problem)
}

/// A calibration as `camera.json`; `observations` are those given to [`build_problem`].
pub fn camera_file(cal: &Calibration, observations: &[Observation]) -> CameraFile {
    let p = &cal.problem;
    let cov = &cal.solution.camera_covariance;
    let sd = |s: Option<usize>| s.map_or(0.0, |s| cov[(s, s)].sqrt());
    let px = p.grid.pixel_size;
    let mut sum = vec![(0.0, 0usize); p.images.len()];
    for o in p.observations.iter().filter(|o| o.active) {
        let r = image_residual(&p.inner, &o.photo, &p.poses[o.image], &p.xyz[o.point]);
        sum[o.image].0 += r.value.norm_squared();
        sum[o.image].1 += 1;
    }
    let stations = p
        .images
        .iter()
        .enumerate()
        .map(|(i, image)| Station {
            image: image.clone(),
            pose: PoseParams::from(p.poses[i]),
            sigma: Some(PoseParams::from_array(std::array::from_fn(|k| {
                sd(p.state_index_pose(i, k))
            }))),
            sigma0: None,
            rms_px: Some((sum[i].0 / (2 * sum[i].1.max(1)) as f64).sqrt() / px),
            observations: Some(sum[i].1),
        })
        .collect();
    let total: (f64, usize) = sum.iter().fold((0.0, 0), |a, s| (a.0 + s.0, a.1 + s.1));
    let m = cov.nrows();
    let names = p.camera_state_names();
    let mut correlations = Vec::new();
    for a in 0..m {
        for b in a + 1..m {
            let r = cov[(a, b)] / (cov[(a, a)] * cov[(b, b)]).sqrt();
            if r.abs() > 0.9 {
                correlations.push(Correlation {
                    a: names[a].clone(),
                    b: names[b].clone(),
                    r,
                });
            }
        }
    }
    let rejected = cal
        .rejected
        .iter()
        .map(|(n, v)| {
            let o = &observations[*n];
            Rejected {
                image: o.image.clone(),
                point: o.point.clone(),
                col: o.col,
                row: o.row,
                residual_px: *v,
            }
        })
        .collect();
    CameraFile {
        format: CAMERA_FORMAT.to_owned(),
        inner: p.inner.into(),
        sigma: InnerParams::from_array(std::array::from_fn(|k| cal.inner_sigma(k))),
        sigma0: Some(cal.solution.sigma0),
        pixel_size: px,
        image_size: [p.grid.width, p.grid.height],
        origin: [p.grid.origin_col, p.grid.origin_row],
        stations,
        correlations,
        rms_px: Some((total.0 / (2 * total.1.max(1)) as f64).sqrt() / px),
        rejected,
        iterations: Some(cal.iterations),
        covariance: Some(InnerCovariance::new(&camera_prior(cal))),
    }
}

/// A camera calibration as the whole-system adjustment's prior: the free inner parameters and
/// their covariance.
pub fn camera_prior(cal: &Calibration) -> CameraPrior {
    let states: Vec<usize> = (0..cal.problem.free.inner.len())
        .filter_map(|k| cal.problem.state_index_inner(k))
        .collect();
    let cov = &cal.solution.camera_covariance;
    CameraPrior {
        free: cal.problem.free.inner,
        covariance: nalgebra::DMatrix::from_fn(states.len(), states.len(), |a, b| {
            cov[(states[a], states[b])]
        }),
    }
}

/// The whole command: read the inputs, calibrate, write `out` atomically. Nothing is written if
/// anything fails. Without a control file the network is free (arbitrary datum and scale).
pub fn calibrate_files(
    init: &Path,
    obs: &Path,
    control: Option<&Path>,
    out: &Path,
    options: &CalibrationOptions,
) -> anyhow::Result<CameraFile> {
    Ok(calibrate_files_with_residuals(init, obs, control, out, options, None)?.0)
}

/// [`calibrate_files`], also writing every observation's residual next to `out`
/// (`camera.residuals.csv`, see [`residuals`]) and, with `plots`, the residual plots into
/// that directory, all together or nothing.
pub fn calibrate_files_with_residuals(
    init: &Path,
    obs: &Path,
    control: Option<&Path>,
    out: &Path,
    options: &CalibrationOptions,
    plots: Option<&Path>,
) -> anyhow::Result<(CameraFile, Vec<residuals::Residual>, Vec<Plot>)> {
    let start = crate::io::camera_file::read_camera(init)?;
    let observations = crate::io::observations::read_observations(obs)?;
    let control = match control {
        Some(path) => crate::io::control::read_control(path)?,
        None => Vec::new(),
    };
    let field = Targets {
        path: obs,
        observations: &observations,
        control: &control,
    };
    let calibration = bundle_field(&start.grid(), &start.inner(), field, options)?;
    let file = camera_file(&calibration, &observations);
    let residuals = residuals::residuals(&calibration, &observations);
    let json = serde_json::to_string_pretty(&file)? + "\n";
    let csv = residuals::residuals_csv(&residuals);
    let csv_path = residuals::residuals_path(out);
    let [width, height] = file.image_size;
    let made = match plots {
        Some(_) => residual_plots(&residuals, width, height)?,
        None => Vec::new(),
    };
    write_with_plots(
        &[(out, json.as_bytes()), (&csv_path, csv.as_bytes())],
        plots,
        &made,
    )?;
    Ok((file, residuals, made))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::camera_file::INNER_NAMES;
    use crate::simulate::{simulate, Scenario, Simulation};
    use deltaz_calib::bundle::problem::FreeParameters;
    use deltaz_calib::residual::POSE;
    use nalgebra::Vector3;

    fn run(sim: &Simulation, options: &CalibrationOptions) -> Calibration {
        let init = &sim.camera_init;
        let problem = build_problem(
            Path::new("camera_obs.csv"),
            &init.grid(),
            &init.inner(),
            &sim.camera_obs,
            &sim.camera_control,
            options,
        )
        .unwrap();
        calibrate(problem, options).unwrap()
    }

    /// Normalised errors (estimate − truth) / σ of f, cx, cy, k1.
    fn z_scores(cal: &Calibration, truth: &InnerParams) -> [f64; 4] {
        let est = InnerParams::from(cal.problem.inner).to_array();
        let t = truth.to_array();
        std::array::from_fn(|k| (est[k] - t[k]) / cal.inner_sigma(k))
    }

    fn paper_sigma0_mm() -> f64 {
        0.5 * 0.045
    }

    /// Paper scenario at 0.5 px: f, cx, cy, k1 within 3σ of truth; σ0 within 20 % of the true
    /// noise; σ of the order of Table 1's (f 0.066 mm, cx 0.052, cy 0.068, k1 1e-6).
    #[test]
    fn paper_scenario_within_3_sigma() {
        let sim = simulate(&Scenario::paper(), 1);
        let cal = run(&sim, &CalibrationOptions::default());
        for (k, z) in z_scores(&cal, &sim.truth.camera.inner).iter().enumerate() {
            assert!(z.abs() < 3.0, "{}: {z:.2}σ", INNER_NAMES[k]);
        }
        let s0 = cal.solution.sigma0;
        assert!((s0 / paper_sigma0_mm() - 1.0).abs() < 0.2, "σ0 {s0} mm");
        let table1 = [0.066, 0.052, 0.068, 1e-6];
        for (k, t) in table1.iter().enumerate() {
            let ratio = cal.inner_sigma(k) / t;
            assert!(
                (0.2..5.0).contains(&ratio),
                "σ {} {ratio}x Table 1",
                INNER_NAMES[k]
            );
        }
        assert!(cal.rejected.len() <= 1, "{:?}", cal.rejected);
        let file = camera_file(&cal, &sim.camera_obs);
        assert_eq!(file.stations.len(), 9);
        assert!((file.rms_px.unwrap() - 0.5).abs() < 0.1);
        assert_eq!(file.sigma.k2, 0.0);
    }

    /// Without noise (and exact, fixed control) the truth comes back exactly.
    #[test]
    fn noise_free_recovers_truth() {
        let mut scenario = Scenario::paper();
        scenario.noise.image_sigma_px = 0.0;
        scenario.field.control_sigma = 0.0;
        let sim = simulate(&scenario, 1);
        let options = CalibrationOptions {
            snooping: false,
            ..CalibrationOptions::default()
        };
        let cal = run(&sim, &options);
        let est = InnerParams::from(cal.problem.inner).to_array();
        for (k, t) in sim.truth.camera.inner.to_array().iter().enumerate() {
            assert!(
                (est[k] - t).abs() < 1e-7 * t.abs().max(1e-3),
                "{}",
                INNER_NAMES[k]
            );
        }
        for (pose, truth) in cal.problem.poses.iter().zip(&sim.truth.stations) {
            assert!(
                (pose.centre - Vector3::new(truth.pose.X0, truth.pose.Y0, truth.pose.Z0)).amax()
                    < 1e-5
            );
        }
    }

    /// Monte Carlo over 200 seeds (≥ 50 asked; ~1 s): the normalised errors of f, cx, cy, k1
    /// have mean near 0 and variance near 1. Bounds: the mean of 200 standard normals has σ 0.071,
    /// and k1 carries a second-order estimator bias of about −0.3σ at 0.5 px (it shrinks to
    /// −0.08σ at 0.1 px, as an O(σ²) bias should), so |mean| < 0.45; the sample variance of 200
    /// has 99.9 % limits 0.70..1.35 (χ²₁₉₉). Control noise (0.1 mm) is part of the stochastic
    /// model, so the σ must cover it. Measured (seeds 200..400): means −0.03, 0.01, −0.06, −0.30;
    /// variances 1.08, 1.00, 1.05, 1.05.
    #[test]
    fn monte_carlo_normalised_errors() {
        let scenario = Scenario::paper();
        let options = CalibrationOptions {
            snooping: false,
            ..CalibrationOptions::default()
        };
        let z: Vec<[f64; 4]> = (200..400)
            .map(|seed| {
                z_scores(
                    &run(&simulate(&scenario, seed), &options),
                    &scenario.camera.inner,
                )
            })
            .collect();
        let n = z.len() as f64;
        for k in 0..4 {
            let mean = z.iter().map(|v| v[k]).sum::<f64>() / n;
            let var = z.iter().map(|v| (v[k] - mean).powi(2)).sum::<f64>() / (n - 1.0);
            println!("{}: mean {mean:.3} variance {var:.3}", INNER_NAMES[k]);
            assert!(mean.abs() < 0.45, "{}: mean {mean}", INNER_NAMES[k]);
            assert!(
                (0.7..1.35).contains(&var),
                "{}: variance {var}",
                INNER_NAMES[k]
            );
        }
    }

    /// 2 % of the observations displaced by 5-20 px are all flagged (20 seeds), at most two good
    /// ones per data set are, and the inner orientation stays within 3σ.
    #[test]
    fn outliers_are_flagged() {
        let mut scenario = Scenario::paper();
        scenario.noise.outlier_rate = 0.02;
        let (mut planted, mut extra) = (0, 0);
        for seed in 1..=20 {
            let sim = simulate(&scenario, seed);
            let cal = run(&sim, &CalibrationOptions::default());
            let flagged: Vec<(&str, &str)> = cal
                .rejected
                .iter()
                .map(|(n, _)| {
                    (
                        sim.camera_obs[*n].image.as_str(),
                        sim.camera_obs[*n].point.as_str(),
                    )
                })
                .collect();
            let outliers = &sim.truth.noise.outliers;
            assert!(!outliers.is_empty());
            for o in outliers {
                assert!(
                    flagged.contains(&(o.image.as_str(), o.point.as_str())),
                    "seed {seed}: {o:?} missed"
                );
            }
            assert!(
                flagged.len() <= outliers.len() + 2,
                "seed {seed}: {} flagged for {}",
                flagged.len(),
                outliers.len()
            );
            for (k, z) in z_scores(&cal, &scenario.camera.inner).iter().enumerate() {
                assert!(z.abs() < 3.0, "seed {seed} {}: {z:.2}σ", INNER_NAMES[k]);
            }
            planted += outliers.len();
            extra += flagged.len() - outliers.len();
        }
        println!("20 seeds: {planted} gross errors planted, all flagged, {extra} good ones too");
    }

    /// A free network (control for approximations only, minimal constraints) gives the same
    /// inner orientation within 3σ, and k2, p1, p2 freed by flag estimate their true zero.
    #[test]
    fn free_network_and_extra_parameters() {
        let sim = simulate(&Scenario::paper(), 4);
        let options = CalibrationOptions {
            free_network: true,
            free: FreeParameters {
                inner: [true, true, true, true, true, false, true, true],
            },
            ..CalibrationOptions::default()
        };
        let cal = run(&sim, &options);
        assert_eq!(cal.problem.num_states_inner(), 7);
        assert_eq!(cal.problem.state_index_pose(0, 0), None);
        let names = cal.problem.camera_state_names();
        assert_eq!(names[..2], ["f", "cx"]);
        assert_eq!(names[cal.problem.state_index_pose(2, 5).unwrap()], "s3.Z0");
        assert_eq!(names.len(), 7 + 6 * 9 - 7);
        for (k, t) in sim.truth.camera.inner.to_array().iter().enumerate() {
            if options.free.inner[k] {
                let z =
                    (InnerParams::from(cal.problem.inner).to_array()[k] - t) / cal.inner_sigma(k);
                assert!(z.abs() < 3.0, "{}: {z:.2}σ", INNER_NAMES[k]);
            }
        }
        assert!(!camera_file(&cal, &sim.camera_obs).correlations.is_empty());
    }

    /// Without any control the network is free: relative orientation, resection, intersection
    /// give the start; the inner orientation is datum-invariant and comes out within 3σ.
    #[test]
    fn no_control_free_network() {
        let sim = simulate(&Scenario::paper(), 6);
        let options = CalibrationOptions::default();
        let problem = build_problem(
            Path::new("camera_obs.csv"),
            &sim.camera_init.grid(),
            &sim.camera_init.inner(),
            &sim.camera_obs,
            &[],
            &options,
        )
        .unwrap();
        assert!(problem.control.iter().all(Option::is_none));
        assert_eq!(problem.pose_free[0], [false; POSE]);
        let cal = calibrate(problem, &options).unwrap();
        for (k, z) in z_scores(&cal, &sim.truth.camera.inner).iter().enumerate() {
            assert!(z.abs() < 3.0, "{}: {z:.2}σ", INNER_NAMES[k]);
        }
        let s0 = cal.solution.sigma0 / paper_sigma0_mm();
        assert!((0.8..1.2).contains(&s0), "σ0 {s0}");
        // Two images sharing fewer than 8 points cannot be oriented relatively.
        let few: Vec<Observation> = sim
            .camera_obs
            .iter()
            .filter(|o| (o.image == "s1" || o.image == "s2") && o.point.as_str() < "T08")
            .cloned()
            .collect();
        let e = build_problem(
            Path::new("camera_obs.csv"),
            &sim.camera_init.grid(),
            &sim.camera_init.inner(),
            &few,
            &[],
            &options,
        )
        .unwrap_err();
        assert!(e.to_string().contains("needs 8"), "{e}");
    }

    /// Malformed input: an error naming file, line and problem, and no output file.
    #[test]
    fn malformed_input_names_file_and_line_and_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let sim = simulate(&Scenario::paper(), 1);
        crate::simulate::write_simulation(d, &sim).unwrap();
        let obs_text = std::fs::read_to_string(d.join("camera_obs.csv")).unwrap();
        let mut lines: Vec<String> = obs_text.lines().map(str::to_owned).collect();
        let out = d.join("camera.json");
        let cases: Vec<(String, &str)> = vec![
            (
                obs_text.replacen("image,point,col,row", "image,point,col,line", 1),
                ":1: missing column `row`",
            ),
            (
                {
                    let mut l = lines.clone();
                    l[5] = l[5].rsplit_once(',').unwrap().0.to_owned() + ",NaN";
                    l.join("\n")
                },
                ":6: `row` is not finite",
            ),
            (
                {
                    let mut l = lines.clone();
                    l[7] = l[7].replacen("T0", "X9", 1);
                    l.join("\n")
                },
                ":8: unknown point \"X9",
            ),
            (
                {
                    let l: Vec<_> = lines
                        .iter()
                        .filter(|l| !l.starts_with("s2") || l.starts_with("image"))
                        .take(40)
                        .cloned()
                        .collect();
                    l.join("\n")
                },
                "only 1 image(s)",
            ),
            (
                {
                    lines.insert(10, lines[9].clone());
                    lines.join("\n")
                },
                ":11: duplicate observation",
            ),
        ];
        for (text, expect) in cases {
            let obs = d.join("bad_obs.csv");
            std::fs::write(&obs, text).unwrap();
            let e = calibrate_files(
                &d.join("camera_init.json"),
                &obs,
                Some(&d.join("camera_control.csv")),
                &out,
                &CalibrationOptions::default(),
            )
            .unwrap_err()
            .to_string();
            assert!(
                e.contains("bad_obs.csv") && e.contains(expect),
                "{e} lacks {expect}"
            );
            assert!(!out.exists());
        }
        let file = calibrate_files(
            &d.join("camera_init.json"),
            &d.join("camera_obs.csv"),
            Some(&d.join("camera_control.csv")),
            &out,
            &CalibrationOptions::default(),
        )
        .unwrap();
        let back = crate::io::camera_file::read_camera(&out).unwrap();
        assert!((back.inner.f - file.inner.f).abs() < 1e-12 && back.stations.len() == 9);
    }
}
