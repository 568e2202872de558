//! `deltaz demo`: the image path end to end on the simulated paper rig.
//!
//! 1. Render the rig's images into `out/images/` (`deltaz simulate --images`): the target field
//!    for the camera, three plates with control and projected dots (each also with the
//!    projector off), and the test objects never used in calibration (`images/objects/`: a
//!    sphere, a tilted plane and the torso, three frames each, with their truth).
//! 2. Measure and identify the field and plate images, calibrate the camera (self-calibrating
//!    bundle adjustment) and then camera and projector together from them alone
//!    ([`crate::workflows::system`]).
//! 3. Upload the system to the device (in process, the firmware's logic over the wire
//!    protocol) with the identification parameters for the objects' depth.
//! 4. Scan the object frames through it ([`crate::workflows::scan`]): measure, identify, intersect;
//!    then a scoliotic back, three swayed frames rendered into `images/back/`, through the
//!    largest back rig the device holds, calibrated and uploaded for it ([`super::back`]), and
//!    analyse it ([`deltaz_surface`]).
//! 5. The accuracy on each object against its truth beside its floor: the image noise (the
//!    calibration's estimated σ of the dots, with the wire's centroid quantisation that the
//!    device computes from) and the calibration's covariance, its share common
//!    to all points carried through the fits ([`crate::report::object_accuracy`]).
//! 6. Write `cloud.ply` (every object point, with its frame), `system.json`, `report.md`,
//!    `report.json` and the plots: the field targets' residuals (`residual_vectors.svg`,
//!    `residual_histogram.svg`) and accuracy maps of the sphere's and the plane's form and
//!    the torso's error (`sphere_errors.svg`, `plane_errors.svg`, `torso_errors.svg`); the
//!    back's cloud (`back.ply`), its rig's calibration (`back_system.json`), its analysis
//!    (`analysis.json`) and its report (`report.html`, as `deltaz analyse back` writes them).

use super::back::{scan_demo_back, DemoBack};
use super::{bar, slashed, v3, write_results};
use crate::io::ply::{encode_with, CloudInfo, Encoding};
use crate::io::system_file::SystemFile;
use crate::link::Device;
use crate::report::back_report::report_html;
use crate::report::calibration_plots::residual_plots;
use crate::report::object_accuracy::{
    error_against_truth, fit_plane, fit_sphere, form, AtFloor, ObjectPoint,
};
use crate::report::plots;
use crate::simulate::images::{true_rig, write_images, ImageSpec};
use crate::simulate::objects::{
    object_dots, plate_depth, test_objects, write_objects, Object, ObjectDot,
};
use crate::simulate::Scenario;
use crate::workflows::scan::{frame_files, identify_params, on_device, scan_files, FramePoints};
use crate::workflows::system::{calibrate_from_images, Known};
use anyhow::{Context, Result};
use deltaz_calib::system_adjustment::Frame;
use deltaz_measure::MeasureParams;
use deltaz_shared::identify::DepthRange;
use deltaz_shared::rig::Method;
use nalgebra::DMatrix;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::Path;

/// Identification depth range about the objects' depth (mm).
const DEPTH_MARGIN_MM: f64 = 130.0;

/// A measured pixel further than this from its ray's true pixel is a wrong identification.
const WRONG_PX: f64 = 1.0;

/// The scanned frames of one object kind: each frame's object and its points.
struct Scanned {
    objects: Vec<Object>,
    points: Vec<Vec<ObjectPoint>>,
}

/// Runs the demo and writes its files into `out` (created if needed): the rendered images
/// first (`out/images/`), the results when everything is computed.
pub fn run(out: &Path, seed: u64) -> Result<serde_json::Value> {
    let steps = bar(6, "rendering the images");
    let scenario = Scenario::paper();
    let spec = ImageSpec::default();
    let images = out.join("images");
    let rendered = write_images(&scenario, seed, &spec, out)?;
    let frames = write_objects(&scenario, seed, out)?;
    steps.inc(1);

    steps.set_message("calibrating from the images");
    let known = Known::simulated(&scenario, &spec, seed)?;
    let cal = calibrate_from_images(&images, &known)?;
    let model = &cal.system.adjustment.model;
    let system = SystemFile::new(cal.system.content.clone())?;
    let fingerprint = system.fingerprint_u64()?;
    steps.inc(1);

    steps.set_message("scanning the objects on the device");
    let depth = plate_depth(&scenario);
    let range = DepthRange {
        near: depth - DEPTH_MARGIN_MM,
        far: depth + DEPTH_MARGIN_MM,
    };
    let mut device = Device::in_process();
    device
        .upload_identifying(
            &cal.rig,
            fingerprint,
            Method::ClosestApproach,
            Some(identify_params(range, 1.0, 16.0)),
        )
        .map_err(|e| anyhow::anyhow!("upload: {e}"))?;
    let files = frame_files(&images.join("objects"))?;
    let mut scanned: Vec<FramePoints> = Vec::new();
    let stats = scan_files(
        &cal.rig,
        &MeasureParams::default(),
        &files,
        on_device(&cal.rig, &mut device),
        |f| {
            scanned.push(f.clone());
            Ok(())
        },
    )?;
    steps.inc(1);

    steps.set_message("scanning a scoliotic back on the device");
    let truth = true_rig(&scenario);
    let back = scan_demo_back(&images, (&spec, seed), &mut device)?;
    let back_json = serde_json::to_string_pretty(&back.report)? + "\n";
    let back_html = report_html(&back.report)?;
    let back_ply = back_cloud(&back)?;
    let back_system = back.system.to_json()?;

    steps.set_message("accuracy against the truth");
    let objects: BTreeMap<String, Object> = test_objects(depth).into_iter().collect();
    let core = model.core_covariance.clone();
    let mut kinds: BTreeMap<&str, Scanned> = BTreeMap::new();
    // The device computes from each dot quantised to q = 2^-bits px (a uniform error, variance
    // q²/12 per coordinate), which adds to the image noise's share of the floor.
    let grid = cal.rig.grid();
    let q = crate::link::centroid_step_px(grid.width, grid.height);
    let s2 = model.sigma_dots_px * model.sigma_dots_px;
    let quantised = (s2 + q * q / 12.0) / s2;
    let split = model.core_split()?;
    let (mut wrong, mut device_vs_host, mut centroid2, mut dots) = (0, 0.0_f64, 0.0, 0);
    let mut cloud = Vec::new();
    let mut cloud_frames = Vec::new();
    for f in &scanned {
        let object = *objects
            .get(&f.label)
            .with_context(|| format!("frame {}: not a test object", f.label))?;
        let true_dots: BTreeMap<u16, ObjectDot> = object_dots(&truth, &object)
            .into_iter()
            .map(|d| (d.0, d))
            .collect();
        let mut points = Vec::new();
        for (dot, p) in f.found.identified.iter().zip(&f.found.points) {
            let hit = true_dots.get(&dot.id);
            let Some((_, (c, r), x)) = hit.filter(|t| {
                let (c, r) = t.1;
                (dot.col - c).hypot(dot.row - r) < WRONG_PX
            }) else {
                wrong += 1;
                continue;
            };
            let mut shares = model
                .reconstruct_shares(&split, grid, dot, Method::ClosestApproach, Frame::Camera)
                .map_err(|e| anyhow::anyhow!("frame {} ray {}: {e}", f.label, dot.id))?;
            shares.image *= quantised;
            device_vs_host = device_vs_host.max((p.point - shares.point).norm());
            centroid2 += (dot.col - c).powi(2) + (dot.row - r).powi(2);
            dots += 1;
            cloud.push(*p);
            cloud_frames.push(f.frame as u32);
            points.push(ObjectPoint {
                point: p.point,
                truth: *x,
                shares,
            });
        }
        let kind = f.label.split('_').next().unwrap_or("");
        let entry = kinds.entry(kind).or_insert(Scanned {
            objects: Vec::new(),
            points: Vec::new(),
        });
        entry.objects.push(object);
        entry.points.push(points);
    }
    let centroid_sigma_px = (centroid2 / (2.0 * dots.max(1) as f64)).sqrt();
    let kind = |k: &str| {
        kinds
            .get(k)
            .with_context(|| format!("no {k} frame was scanned"))
    };
    let (sphere, sphere_map) = sphere_figures(kind("sphere")?, &core)?;
    let (plane, plane_map) = plane_figures(kind("plane")?, &core)?;
    let torso = kind("torso")?;
    let torso_error = error_against_truth(&torso.points.concat(), &core);
    let torso_map: Vec<_> = torso.points[0]
        .iter()
        .map(|p| (p.truth.x, p.truth.y, p.point.z - p.truth.z))
        .collect();
    steps.inc(1);

    steps.set_message("plots and report");
    let mut plot_files = residual_plots(&cal.residuals, grid.width, grid.height)?;
    plot_files.extend([
        (
            "sphere_errors.svg".to_owned(),
            plots::accuracy_map(
                "Sphere (frame sphere_0) against the fitted sphere, camera system",
                "Form error",
                &sphere_map,
            )?,
        ),
        (
            "plane_errors.svg".to_owned(),
            plots::accuracy_map(
                "Tilted plane (frame plane_0) against the fitted plane, camera system",
                "Flatness error",
                &plane_map,
            )?,
        ),
        (
            "torso_errors.svg".to_owned(),
            plots::accuracy_map(
                "Torso (frame torso_0) against its truth, camera system",
                "Z error",
                &torso_map,
            )?,
        ),
    ]);
    let inner = model.inner;
    let inner_truth = scenario.camera.inner;
    let sigma = &cal.camera.sigma;
    let report = json!({
        "format": "deltaz.demo/2",
        "path": "images",
        "scenario": scenario.name,
        "seed": seed,
        "images": {
            "rendered": rendered,
            "object_frames": frames,
            "size_px": [grid.width, grid.height],
            "noise_dn": spec.noise_sigma,
            "blur_px": spec.blur_sigma,
        },
        "calibration": {
            "field_targets": cal.field.observations.len(),
            "plate_observations": cal.plates.observations.len(),
            "camera": {
                "f_mm": inner.f, "cx_mm": inner.cx, "cy_mm": inner.cy, "k1": inner.k1,
                "sigma": {"f_mm": sigma.f, "cx_mm": sigma.cx, "cy_mm": sigma.cy, "k1": sigma.k1},
                "truth": {"f_mm": inner_truth.f, "cx_mm": inner_truth.cx, "cy_mm": inner_truth.cy, "k1": inner_truth.k1},
            },
            "projector": {
                "centre_mm": v3(&model.centre),
                "centre_sigma_mm": v3(&model.centre_sigma()),
                "centre_truth_mm": scenario.rig.projector_centre,
                "rays": model.rays.len(),
            },
            "sigma_targets_px": cal.system.adjustment.sigma_targets_px,
            "sigma_dots_px": model.sigma_dots_px,
            "fingerprint": system.fingerprint,
        },
        "scan": {
            "frames": stats.frames,
            "points": stats.points,
            "wrong_identifications": wrong,
            "centroid_sigma_px": centroid_sigma_px,
            "device_vs_host_max_mm": device_vs_host,
            "frames_per_second": stats.frames_per_second(),
        },
        "objects": {
            "sphere": sphere,
            "plane": plane,
            "torso": {"error": torso_error},
        },
        "back": back_figures(&back),
    });
    let md = report_markdown(&report)?;
    let info = CloudInfo {
        frame: system.content.frame.to_string(),
        fingerprint: Some(system.fingerprint.clone()),
        frames: Some(cloud_frames),
        centroid_step_px: Some(q),
    };
    let ply = encode_with(&cloud, Encoding::BinaryLittleEndian, &info);
    steps.finish_and_clear();

    let extra: [(&str, &[u8]); 4] = [
        ("back.ply", &back_ply),
        ("back_system.json", back_system.as_bytes()),
        ("analysis.json", back_json.as_bytes()),
        ("report.html", back_html.as_bytes()),
    ];
    write_results(out, &ply, &system, &plot_files, (&report, &md), &extra)?;
    Ok(report)
}

/// An accuracy map's points: (X, Y, error), mm.
type MapPoints = Vec<(f64, f64, f64)>;

/// The sphere's figures: per frame the radius error and its σ, the form error over all frames;
/// and the 1st frame's form residuals for its map.
fn sphere_figures(s: &Scanned, core: &DMatrix<f64>) -> Result<(serde_json::Value, MapPoints)> {
    let mut fits = Vec::new();
    let (mut errors, mut sigmas) = (Vec::new(), Vec::new());
    for (object, points) in s.objects.iter().zip(&s.points) {
        let Object::Sphere { radius, .. } = *object else {
            anyhow::bail!("a sphere frame holds a {object:?}");
        };
        let fit = fit_sphere(points, core).context("the sphere fit failed")?;
        errors.push(fit.params[3] - radius);
        sigmas.push(fit.covariance[(3, 3)].sqrt());
        fits.push(fit);
    }
    let map = map_of(&s.points[0], &fits[0].residuals);
    let form = form(&fits);
    Ok((
        json!({"radius_error_mm": errors, "radius_sigma_mm": sigmas, "form": form}),
        map,
    ))
}

/// The plane's flatness over all frames, and the 1st frame's residuals for its map.
fn plane_figures(s: &Scanned, core: &DMatrix<f64>) -> Result<(serde_json::Value, MapPoints)> {
    let fits = s
        .points
        .iter()
        .map(|p| fit_plane(p, core).map(|(fit, _)| fit))
        .collect::<Option<Vec<_>>>()
        .context("a plane fit failed")?;
    let map = map_of(&s.points[0], &fits[0].residuals);
    Ok((json!({"flatness": form(&fits)}), map))
}

/// (X, Y, residual) of each point, for an accuracy map.
fn map_of(points: &[ObjectPoint], residuals: &nalgebra::DVector<f64>) -> MapPoints {
    points
        .iter()
        .zip(residuals.iter())
        .map(|(p, r)| (p.point.x, p.point.y, *r))
        .collect()
}

/// A figure and its floor as people read it: "0.0449 mm (floor 0.0457 mm, 0.98 ×)".
fn at_floor(v: &serde_json::Value) -> Result<String> {
    let a: AtFloor = serde_json::from_value(v.clone())?;
    Ok(format!(
        "{:.4} mm (floor {:.4} mm, {:.2} ×, {} points)",
        a.rms_mm,
        a.floor_mm,
        a.ratio(),
        a.points
    ))
}

/// The back's cloud as `deltaz scan` would write it (`back.ply`).
fn back_cloud(back: &DemoBack) -> Result<Vec<u8>> {
    let system = &back.system;
    let frames = &back.scanned.frames;
    let points: Vec<_> = frames.iter().flat_map(|f| f.found.points.clone()).collect();
    let info = CloudInfo {
        frame: system.content.frame.to_string(),
        fingerprint: Some(system.fingerprint.clone()),
        frames: Some(
            frames
                .iter()
                .flat_map(|f| std::iter::repeat_n(f.frame as u32, f.found.points.len()))
                .collect(),
        ),
        centroid_step_px: back.scanned.cloud.centroid_step_px,
    };
    Ok(encode_with(&points, Encoding::BinaryLittleEndian, &info))
}

/// The back's figures: its scan, the largest surface rotation and the symmetry line's ends
/// against the model's truth at the analysis' levels.
fn back_figures(back: &DemoBack) -> serde_json::Value {
    let a = &back.scanned.analysis;
    let axes = crate::simulate::back::Axes {
        across: a.axes.across.into(),
        axis: a.axes.axis.into(),
        up: a.axes.up.into(),
    };
    let model = &back.models[0];
    let truth = a
        .levels
        .iter()
        .filter_map(|l| model.rotation(&axes, l.y))
        .map(f64::to_degrees)
        .fold(0.0_f64, |m, r| if r.abs() > m.abs() { r } else { m });
    json!({
        "frames": back.scanned.frames.len(),
        "points": back.scanned.cloud.vertices.len(),
        "levels": a.levels.len(),
        "spacing_mm": a.spacing_mm,
        "rotation_max_deg": a.rotation_max_deg,
        "rotation_max_sigma_deg": a.rotation_max_deg_sigma,
        "rotation_max_truth_deg": truth,
        "lateral_deviation_max_mm": a.lateral_deviation_max_mm,
        "lateral_deviation_max_sigma_mm": a.lateral_deviation_max_mm_sigma,
    })
}

/// The one-line summary `deltaz demo` prints.
pub fn summary(report: &serde_json::Value) -> Result<String> {
    let o = &report["objects"];
    let b = &report["back"];
    let num = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    Ok(format!(
        "sphere form {}\nplane flatness {}\ntorso error {}\nscoliotic back ({} frames through \
         the device, dots {:.0} mm apart): largest surface rotation {:.1} ± {:.1}° (truth \
         {:.1}°), report.html",
        at_floor(&o["sphere"]["form"])?,
        at_floor(&o["plane"]["flatness"])?,
        at_floor(&o["torso"]["error"])?,
        b["frames"],
        num(&b["spacing_mm"]),
        num(&b["rotation_max_deg"]),
        num(&b["rotation_max_sigma_deg"]),
        num(&b["rotation_max_truth_deg"]),
    ))
}

fn report_markdown(r: &serde_json::Value) -> Result<String> {
    let num = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let c = &r["calibration"];
    let cam = &c["camera"];
    let p = &c["projector"];
    let s = &r["scan"];
    let o = &r["objects"];
    let radius: Vec<String> = o["sphere"]["radius_error_mm"]
        .as_array()
        .into_iter()
        .flatten()
        .zip(
            o["sphere"]["radius_sigma_mm"]
                .as_array()
                .into_iter()
                .flatten(),
        )
        .map(|(e, s)| format!("{:+.4} ± {:.4}", num(e), num(s)))
        .collect();
    Ok(format!(
        "# deltaz demo: the paper rig from rendered images\n\n\
         Scenario `{}`, seed {}: {} images rendered ({} × {} px, noise {} DN, blur {} px) and {} \
         frames of test objects, in `images/`. Calibration fingerprint `{}`.\n\n\
         ## Calibration from the images\n\n\
         {} field targets and {} plate observations measured and identified.\n\n\
         | | f (mm) | cx (mm) | cy (mm) | k1 |\n|---|---|---|---|---|\n\
         | estimated | {:.4} | {:.4} | {:.4} | {:.3e} |\n\
         | σ (bundle) | {:.4} | {:.4} | {:.4} | {:.1e} |\n\
         | truth | {:.4} | {:.4} | {:.4} | {:.3e} |\n\n\
         Projector centre in the camera system (X / Y / Z): {} mm, σ {} mm; truth {} mm; {} rays. \
         Image noise estimated by the system adjustment: targets {:.4} px, dots {:.4} px.\n\n\
         ## Test objects scanned through the device (in process)\n\n\
         {} frames, {} points ({:.0} frames/s), {} wrong identifications; centroid error against \
         the truth {:.4} px per axis; device (f32, fixed-point wire) vs host f64 at most {:.4} mm.\n\
         Each figure beside its floor (image noise at the estimated dot σ with the wire's \
         centroid quantisation, and the calibration's covariance, its common share carried \
         through the fits):\n\n\
         | object (3 frames each) | figure |\n|---|---|\n\
         | sphere, radius 300 mm: radius error ± σ per frame | {} mm |\n\
         | sphere: form error (RMS distance from the fitted sphere) | {} |\n\
         | tilted plane: flatness (RMS distance from the fitted plane) | {} |\n\
         | torso: 3D error against the truth (RMS) | {} |\n\n\
         Plots: `residual_vectors.svg` and `residual_histogram.svg` (the field targets' residuals \
         in the camera calibration, px), `sphere_errors.svg`, `plane_errors.svg` (form residuals, \
         mm) and `torso_errors.svg` (Z error against the truth, mm) over X, Y.\n",
        r["scenario"].as_str().unwrap_or(""),
        r["seed"],
        r["images"]["rendered"],
        r["images"]["size_px"][0],
        r["images"]["size_px"][1],
        r["images"]["noise_dn"],
        r["images"]["blur_px"],
        r["images"]["object_frames"],
        c["fingerprint"].as_str().unwrap_or(""),
        c["field_targets"],
        c["plate_observations"],
        num(&cam["f_mm"]),
        num(&cam["cx_mm"]),
        num(&cam["cy_mm"]),
        num(&cam["k1"]),
        num(&cam["sigma"]["f_mm"]),
        num(&cam["sigma"]["cx_mm"]),
        num(&cam["sigma"]["cy_mm"]),
        num(&cam["sigma"]["k1"]),
        num(&cam["truth"]["f_mm"]),
        num(&cam["truth"]["cx_mm"]),
        num(&cam["truth"]["cy_mm"]),
        num(&cam["truth"]["k1"]),
        slashed(&p["centre_mm"]),
        slashed(&p["centre_sigma_mm"]),
        slashed(&p["centre_truth_mm"]),
        p["rays"],
        num(&c["sigma_targets_px"]),
        num(&c["sigma_dots_px"]),
        s["frames"],
        s["points"],
        num(&s["frames_per_second"]),
        s["wrong_identifications"],
        num(&s["centroid_sigma_px"]),
        num(&s["device_vs_host_max_mm"]),
        radius.join(", "),
        at_floor(&o["sphere"]["form"])?,
        at_floor(&o["plane"]["flatness"])?,
        at_floor(&o["torso"]["error"])?,
    ))
}
