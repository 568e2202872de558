//! `deltaz simulate --images` for the paper scenario: the rendered images measured back against
//! their true centres, and the plate's dots identified with the true rig.

use deltaz_host::io::observations::{read_observations, PointKind};
use deltaz_host::simulate::images::{true_rig, write_images, ImageSpec};
use deltaz_host::simulate::Scenario;
use deltaz_host::workflows::observations::measure_images;
use deltaz_measure::{measure_file, HostIdentifier, MeasureParams};
use deltaz_shared::identify::{Assignment, DepthRange, Identifier};

#[test]
fn paper_images_measured_and_identified() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = Scenario::paper();
    assert_eq!(
        write_images(&scenario, 1, &ImageSpec::default(), dir.path()).unwrap(),
        15
    );
    let centres = read_observations(&dir.path().join("images/centres.csv")).unwrap();

    let rig = true_rig(&scenario);

    for image in ["s1", "s5", "p1", "p2", "p3"] {
        let truth: Vec<_> = centres.iter().filter(|c| c.image == image).collect();
        // The working range: ±60 mm about the plate image's camera height (stations: 2.3 m).
        let z0 = scenario
            .plate
            .images
            .get(usize::from(image.as_bytes()[1] - b'1'))
            .map_or(2300.0, |p| p.Z0);
        let depth = DepthRange {
            near: z0 - 60.0,
            far: z0 + 60.0,
        };
        let ident =
            Box::new(Identifier::<f64, 512, 2048, 8192>::new(&rig, depth, 1.0, 16.0).unwrap());
        let m = measure_file(
            &dir.path().join(format!("images/{image}.png")),
            &MeasureParams::default(),
        )
        .unwrap();
        let (mut sum2, mut matched, mut merged) = (0.0, 0, 0);
        let (mut dots, mut dots_ok, mut dots_wrong, mut targets_taken) = (0, 0, 0, 0);
        for t in &m.targets {
            let (best, miss) = truth
                .iter()
                .map(|c| (c, (c.col - t.col).hypot(c.row - t.row)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            if miss >= 0.5 {
                // Only a blob of two overlapping spots (a dot on a target) may be off.
                let near = truth
                    .iter()
                    .filter(|c| (c.col - t.col).hypot(c.row - t.row) < 12.0)
                    .count();
                assert!(
                    near >= 2,
                    "{image}: measured ({}, {}) is no true centre",
                    t.col,
                    t.row
                );
                merged += 1;
                continue;
            }
            sum2 += miss * miss;
            matched += 1;
            let assigned = ident.identify(t.col, t.row);
            match best.kind {
                PointKind::Dot => {
                    dots += 1;
                    match assigned {
                        Assignment::Ray { id, .. } if id.to_string() == best.point => dots_ok += 1,
                        Assignment::Ray { .. } => dots_wrong += 1,
                        _ => {}
                    }
                }
                PointKind::Control => targets_taken += usize::from(assigned.id().is_some()),
            }
        }
        let rms = (sum2 / matched as f64).sqrt();
        println!(
            "{image}: {} true, {matched} measured (RMS {rms:.4} px), {merged} merged accepted, {} rejected; dots {dots}: {dots_ok} identified, {dots_wrong} wrong; targets taken for dots {targets_taken}",
            truth.len(),
            m.rejected.len()
        );
        assert!(rms < 0.03, "{image}: RMS {rms}");
        assert!(
            matched as f64 >= 0.9 * truth.len() as f64,
            "{image}: {matched} of {}",
            truth.len()
        );
        assert_eq!(dots_wrong, 0, "{image}");
        assert!(
            merged as f64 <= 0.02 * truth.len() as f64,
            "{image}: {merged} merged blobs accepted"
        );
        if image.starts_with('p') {
            assert!(
                dots_ok as f64 >= 0.99 * dots as f64,
                "{image}: {dots_ok} of {dots}"
            );
        }
    }

    // The `deltaz measure --system` path: p2's dots as `dot` rows with their ray ids, every
    // other blob (the control targets) reported, none written.
    let depth = DepthRange {
        near: 1680.0,
        far: 1800.0,
    };
    // The host identifier is about 0.6 MB, built on the stack: give it a big one.
    let host = std::thread::scope(|s| {
        std::thread::Builder::new()
            .stack_size(16 << 20)
            .spawn_scoped(s, || {
                Box::new(HostIdentifier::new(&rig, depth, 1.0, 16.0).unwrap())
            })
            .unwrap()
            .join()
            .unwrap()
    });
    let p2 = dir.path().join("images/p2.png");
    let measured = measure_images(&[p2], &MeasureParams::default(), Some(&host)).unwrap();
    let truth: Vec<_> = centres.iter().filter(|c| c.image == "p2").collect();
    for o in &measured.observations {
        assert_eq!(o.kind, PointKind::Dot);
        let same = truth.iter().find(|c| c.point == o.point).unwrap();
        assert!(
            (same.col - o.col).hypot(same.row - o.row) < 0.1,
            "ray {}",
            o.point
        );
    }
    let targets = truth
        .iter()
        .filter(|c| c.kind == PointKind::Control)
        .count();
    println!(
        "p2 via measure_images: {} dots written, {} reported",
        measured.observations.len(),
        measured.unidentified.len()
    );
    assert!(measured.observations.len() >= 420);
    assert!(
        measured.unidentified.len() <= targets
            && measured.unidentified.iter().all(|l| l.starts_with("p2 m"))
    );
}

/// Projector calibration has no rays yet: the plate dots are labelled by walking the pattern's
/// grid from the larger marker dot. No wrong label, at least 99 % of the measured dots labelled.
#[test]
fn plate_dots_by_grid_topology() {
    use deltaz_measure::grid::walk_grid;
    use nalgebra::Vector2;
    let dir = tempfile::tempdir().unwrap();
    let scenario = Scenario::paper();
    let spec = ImageSpec::default();
    write_images(&scenario, 3, &spec, dir.path()).unwrap();
    let centres = read_observations(&dir.path().join("images/centres.csv")).unwrap();
    let pattern = &scenario.rig.pattern;
    let (mr, mc) = spec.marker_node.unwrap();
    for image in ["p1", "p2", "p3"] {
        let truth: Vec<_> = centres
            .iter()
            .filter(|c| c.image == image && c.kind == PointKind::Dot)
            .collect();
        let m = measure_file(
            &dir.path().join(format!("images/{image}.png")),
            &MeasureParams::default(),
        )
        .unwrap();
        let dots: Vec<Vector2<f64>> = m
            .targets
            .iter()
            .map(|t| Vector2::new(t.col, t.row))
            .collect();
        // The marker: the largest fitted ellipse among the dots (the distinct control targets
        // are larger still; `identify_images` tells them apart by the layout match).
        let is_dot = |k: usize| {
            let t = &m.targets[k];
            truth
                .iter()
                .any(|c| (c.col - t.col).hypot(c.row - t.row) < 0.5)
        };
        let size = |k: usize| {
            m.targets[k]
                .fit
                .filter(|_| is_dot(k))
                .map_or(0.0, |f| f.semi_major * f.semi_minor)
        };
        let marker = (0..dots.len())
            .max_by(|&a, &b| size(a).total_cmp(&size(b)))
            .unwrap();
        let labels = walk_grid(
            &dots,
            marker,
            (i32::from(mr), i32::from(mc)),
            Vector2::new(1.0, 0.0),
            Vector2::new(0.0, -1.0),
            (20, 22),
        );
        let (mut labelled, mut wrong, mut dots_measured) = (0, 0, 0);
        for (d, label) in dots.iter().zip(&labels) {
            let (best, miss) = truth
                .iter()
                .map(|c| (c, (c.col - d.x).hypot(c.row - d.y)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            let is_dot = miss < 0.5;
            dots_measured += usize::from(is_dot);
            if let Some((r, c)) = label {
                labelled += 1;
                let id = pattern.id(*r as u16, *c as u16).to_string();
                // A blob of a dot merged with a target is off by its partner's pull but still
                // the right node; only the label is judged here.
                if id != best.point || miss > 5.0 {
                    wrong += 1;
                }
            }
        }
        println!("{image}: {} measured blobs, {dots_measured} dots, {labelled} labelled by the grid walk, {wrong} wrong", dots.len());
        assert_eq!(wrong, 0, "{image}");
        assert!(
            labelled as f64 >= 0.99 * dots_measured as f64,
            "{image}: {labelled} of {dots_measured}"
        );
    }
}
