//! Bad input across every command, one table: each case must exit with code 1, print one clean
//! `error: ...` chain naming the file (with its line or field) or the option and the problem,
//! never panic or print a backtrace (RUST_BACKTRACE=1 is set), and leave its directory exactly
//! as it was: no output file created or changed.

use crate::cli::{deltaz_ok, paper_rig, words};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// The good files the cases start from: the simulated paper rig (sim/), the true camera
/// (camera.json), a calibrated system (system.json), the 1st plate image's dots (dots.csv),
/// and the images rendered from the same simulation (in [`images_parent`]).
fn fixture() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bad_input_fixture");
        // The lock covers the rendered images too.
        deltaz_testkit::fixture(&dir.with_extension("lock"), move || {
            let scenario = paper_rig(&dir, 0.1, 5, &words("--image-sigma-px 0.1"));
            let spec = deltaz_host::simulate::images::ImageSpec::default();
            // The images outside the fixture (not copied for every case).
            deltaz_host::simulate::images::write_images(&scenario, 5, &spec, &images_parent()).unwrap();
            let plate = std::fs::read_to_string(dir.join("sim/plate_obs.csv")).unwrap();
            let dots: String = plate
                .lines()
                .take(1)
                .chain(
                    plate
                        .lines()
                        .filter(|l| l.starts_with("p1,") && l.ends_with(",dot")),
                )
                .map(|l| format!("{l}\n"))
                .collect();
            std::fs::write(dir.join("dots.csv"), dots).unwrap();
            // A cloud of several images, as PLY and CSV.
            deltaz_ok(
                &dir,
                &words("reconstruct --system system.json --obs sim/plate_obs.csv --out multi.ply --csv multi.csv"),
            );
            dir
        })
    })
}

/// The fixture's rendered images are in `images/` here.
fn images_parent() -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join("bad_input_images")
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                files.insert(path.clone(), std::fs::read(&path).unwrap());
            }
        }
    }
    files
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let target = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_dir(&path, &target);
        } else {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

/// One bad input: the files written over the fixture, the command line, what the error must say.
struct Case {
    files: Vec<(&'static str, Vec<u8>)>,
    args: Vec<String>,
    expect: Vec<&'static str>,
}

fn case(args: &str, expect: &[&'static str]) -> Case {
    Case {
        files: Vec::new(),
        args: args.split_whitespace().map(String::from).collect(),
        expect: expect.to_vec(),
    }
}

impl Case {
    fn with(mut self, name: &'static str, bytes: impl Into<Vec<u8>>) -> Self {
        self.files.push((name, bytes.into()));
        self
    }
}

/// A fixture file with one edit.
fn edited(name: &str, from: &str, to: &str) -> String {
    let text = std::fs::read_to_string(fixture().join(name)).unwrap();
    assert!(text.contains(from), "{name} lacks {from:?}");
    text.replacen(from, to, 1)
}

/// The fixture's system.json with its rays repeated to 900 (new ids), more than a device holds.
fn oversized_system() -> String {
    use deltaz_host::io::system_file::SystemFile;
    let text = std::fs::read_to_string(fixture().join("system.json")).unwrap();
    let mut content = serde_json::from_str::<SystemFile>(&text).unwrap().content;
    let rays = content.projector.rays.clone();
    content.projector.rays = (0..1400)
        .map(|k| deltaz_host::io::system_file::SystemRay {
            id: k as u16,
            ..rays[k % rays.len()].clone()
        })
        .collect();
    serde_json::to_string(&SystemFile::new(content).unwrap()).unwrap()
}

/// A 4 × 3 greyscale TIFF with 32-bit floating-point samples.
fn float_tiff() -> Vec<u8> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    tiff::encoder::TiffEncoder::new(&mut bytes)
        .unwrap()
        .write_image::<tiff::encoder::colortype::Gray32Float>(4, 3, &[0.5f32; 12])
        .unwrap();
    bytes.into_inner()
}

/// A rendered image of the fixture, as its PNG bytes.
fn image_bytes(name: &str) -> Vec<u8> {
    fixture();
    std::fs::read(images_parent().join("images").join(name)).unwrap()
}

/// A rendered image of the fixture resized from 768 × 512 to 576 × 384 pixels (PNG).
fn resized(name: &str) -> Vec<u8> {
    let image = image::load_from_memory(&image_bytes(name)).unwrap();
    let small = image.resize_exact(576, 384, image::imageops::FilterType::Triangle);
    let mut bytes = std::io::Cursor::new(Vec::new());
    small.write_to(&mut bytes, image::ImageFormat::Png).unwrap();
    bytes.into_inner()
}

/// The fixture's camera.json with a 640 × 480 sensor instead of 768 × 512.
fn small_camera() -> String {
    let text = edited("camera.json", "768,", "640,");
    assert_eq!(text.matches("512").count(), 1);
    text.replace("512", "480")
}

const SCENARIO: &str = include_str!("../../scenarios/desk_rig.toml");

fn cases() -> Vec<Case> {
    let calibrate_camera = "calibrate camera --init camera.json --obs sim/camera_obs.csv \
                            --control sim/camera_control.csv --out cam.json";
    let projector = "calibrate projector --camera camera.json --control sim/plate_control.csv \
                     --obs sim/plate_obs.csv --out sys.json";
    let resect = "resect --camera camera.json --obs sim/plate_obs.csv \
                  --control sim/plate_control.csv --out poses.json";
    let reconstruct = "reconstruct --system system.json --obs dots.csv --out cloud.ply";
    let compare = "compare --reconstructed a.csv --reference sim/plate_control.csv";
    let system = "calibrate system --init camera.json --camera-obs sim/camera_obs.csv \
                  --camera-control sim/camera_control.csv --control sim/plate_control.csv \
                  --obs sim/plate_obs.csv --out all.json";
    let scan = "scan frames --system system.json --near 1600 --far 1900 --out clouds";
    let points = "point,X,Y,Z\nC01,0,-40,0\nC02,190,-40,0\nC03,375,-40,0\nC07,190,240,200\n";
    vec![
        // simulate
        case("simulate --scenario nope.toml --out o", &["nope.toml", "No such file"]),
        case("simulate --scenario s.toml --out o", &["s.toml", "camera.image_size 200000 x 150000", "limit"])
            .with("s.toml", SCENARIO.replace("[2048, 1536]", "[200000, 150000]")),
        case("simulate --scenario s.toml --out o", &["s.toml", "line 7", "unknown field `pixel_sise`"])
            .with("s.toml", SCENARIO.replace("pixel_size", "pixel_sise")),
        case("simulate --scenario s.toml --out o", &["s.toml", "stations.count 4000000000", "limit"])
            .with("s.toml", SCENARIO.replace("count = 9", "count = 4000000000")),
        case("simulate --scenario s.toml --out o", &["s.toml", "σ must not be negative"])
            .with("s.toml", SCENARIO.replace("image_sigma_px = 0.1", "image_sigma_px = -0.1")),
        // compare
        case(compare, &["a.csv:1: missing column `Z`"]).with("a.csv", "point,X,Y\nC01,1,2\n"),
        case(compare, &["a.csv:3: 5 fields but the header has 4", "decimal comma"])
            .with("a.csv", "point,X,Y,Z\nC01,0,-40,0\nC02,190,-40,0,5\n"),
        case(compare, &["a.csv:4: `Z` is not a number: \"x\""])
            .with("a.csv", points.replace("375,-40,0", "375,-40,x").replace('\n', "\r\n")),
        case(compare, &["a.csv:2: `X` is not finite"]).with("a.csv", points.replace("0,-40,0", "NaN,-40,0")),
        case(compare, &["point \"Q9\" is not in the reference"]).with("a.csv", format!("{points}Q9,1,2,3\n")),
        case(compare, &["a.csv", "collinear"])
            .with("a.csv", "point,X,Y,Z\nC01,0,0,0\nC02,1,1,1\nC03,2,2,2\nC04,3,3,3.0001\n"),
        case(compare, &["a.csv: no control points"]).with("a.csv", "point,X,Y,Z\n"),
        case(compare, &["a.csv:3: duplicate control point \"C01\""])
            .with("a.csv", "point,X,Y,Z\nC01,0,0,0\nC01,1,1,1\n"),
        // reconstruct
        case("reconstruct --system none.json --obs dots.csv --out c.ply", &["none.json", "No such file"]),
        case(reconstruct, &["system.json", "not a valid system.json", "line 1"]).with("system.json", "{\"format\": "),
        case(reconstruct, &["system.json", "fingerprint", "edited by hand"])
            .with("system.json", edited("system.json", "\"miss_rms\": ", "\"miss_rms\": 1")),
        case(reconstruct, &["dots.csv", "ray 2121"]).with("dots.csv", "image,point,col,row\nf1,2121,300,200\n"),
        case(reconstruct, &["dots.csv:2: point \"A\" is not a ray id"]).with("dots.csv", "image,point,col,row\nf1,A,300,200\n"),
        case(&format!("{reconstruct} --sigma-px NaN"), &["--sigma-px", "NaN is not a positive finite number"]),
        case(&format!("{reconstruct} --sigma-px 0"), &["--sigma-px", "0 is not a positive finite number"]),
        case(&format!("{reconstruct} --csv nodir/c.csv"), &["nodir/c.csv", "cannot write"]),
        // The cloud's target is a folder: the CSV is not written either.
        case("reconstruct --system system.json --obs dots.csv --out adir --csv c.csv", &["adir: cannot write: it is a directory"])
            .with("adir/keep", ""),
        // resect
        case(resect, &["camera.json", "`image_size` 4294967295 x 512 px exceeds the limit"])
            .with("camera.json", edited("camera.json", "768,", "4294967295,")),
        case(resect, &["camera.json", "`inner.f` 1e300 mm", "not a focal length"])
            .with("camera.json", edited("camera.json", "\"f\": 46.981", "\"f\": 1e300")),
        case(resect, &["plate_control.csv:2: `X` is 1e308 mm, beyond"])
            .with("sim/plate_control.csv", "point,X,Y,Z\nC01,1e308,0,0\nC02,1,0,0\n"),
        case(resect, &["plate_obs.csv:1: missing column `row`"])
            .with("sim/plate_obs.csv", "image,point,col,kind\np1,C01,1,control\n"),
        case(resect, &["plate_obs.csv:4: `col` is not a number: \"x"])
            .with("sim/plate_obs.csv", edited("sim/plate_obs.csv", "p1,C03,", "p1,C03,x").replace('\n', "\r\n")),
        case(resect, &["plate_obs.csv:3: duplicate observation of point \"C01\""])
            .with("sim/plate_obs.csv", "image,point,col,row\np1,C01,1,2\np1,C01,3,4\n"),
        case(resect, &["plate_obs.csv:2: `kind` must be `control` or `dot`"])
            .with("sim/plate_obs.csv", "image,point,col,row,kind\np1,C01,1,2,target\n"),
        case(resect, &["camera.json", "missing field `pixel_size`"])
            .with("camera.json", edited("camera.json", "\"pixel_size\"", "\"pixel_sise\"")),
        // calibrate camera
        case(&format!("{calibrate_camera} --image-sigma-px 0"), &["--image-sigma-px", "0 is not a positive"]),
        case(&format!("{calibrate_camera} --image-sigma-px -1"), &["--image-sigma-px", "-1 is not a positive"]),
        case(&format!("{calibrate_camera} --image-sigma-px NaN"), &["--image-sigma-px", "NaN is not a positive"]),
        case(calibrate_camera, &["camera_obs.csv: no observations"]).with("sim/camera_obs.csv", "image,point,col,row\n"),
        case(calibrate_camera, &["camera_control.csv:2: `sigma` is negative"])
            .with("sim/camera_control.csv", edited("sim/camera_control.csv", ",0.1\n", ",-0.1\n")),
        case("calibrate camera --init camera.json --images nodir --control sim/camera_control.csv --out cam.json", &["nodir"]),
        // A plots folder that cannot be made: neither the camera nor its residuals are written.
        case(&format!("{calibrate_camera} --plots taken"), &["taken: cannot create"]).with("taken", ""),
        // A resized image is refused as one, not as a layout that does not match.
        case("calibrate camera --init camera.json --images small --control sim/camera_control.csv --out cam.json",
            &["small/s1.png: the image size differs from the expected one: 576 × 384 pixels, the camera's sensor 768 × 512"])
            .with("small/s1.png", resized("s1.png")),
        // A pixel size that is no pixel size.
        case("calibrate camera --board circles:7x7 --images boards --out c.json --pixel-size -1",
            &["--pixel-size", "-1 is not a positive finite number"]),
        case("calibrate camera --board circles:7x7 --images boards --out c.json --pixel-size 0",
            &["--pixel-size", "0 is not a positive finite number"]),
        case("calibrate camera --board circles:7x7 --images boards --out c.json --pixel-size NaN",
            &["--pixel-size", "NaN is not a positive finite number"]),
        case("calibrate camera --board circles:7x7 --images boards --out c.json --pixel-size 1e30",
            &["--pixel-size", "1e30 mm is not a pixel size (at most 1 mm)"]),
        // Bright targets where a board's dark circles are expected: the hint names a flag that
        // this command, and `measure`, takes; `measure --board` expects dark circles too.
        case("calibrate camera --board circles:7x7 --images boards --out c.json",
            &["boards/s1.png: no targets found", "bright targets found with --bright"])
            .with("boards/s1.png", image_bytes("s1.png")),
        case("measure boards/s1.png --board circles:7x7 --out m.csv",
            &["boards/s1.png: no targets found", "bright targets found with --bright"])
            .with("boards/s1.png", image_bytes("s1.png")),
        // calibrate projector
        case(&format!("{projector} --image-sigma-px 0"), &["--image-sigma-px", "0 is not a positive"]),
        // Observations of another camera than camera.json's, refused as reconstruct refuses them.
        case(&projector.replace("camera.json", "small.json"), &["plate_obs.csv:", "is off the 640 × 480 sensor"])
            .with("small.json", small_camera()),
        case(&resect.replace("camera.json", "small.json"), &["plate_obs.csv:", "is off the 640 × 480 sensor"])
            .with("small.json", small_camera()),
        // A system file where a camera file belongs: named as what it is.
        case(&projector.replace("camera.json", "system.json"),
            &["system.json: format \"deltaz.system/2\": a system calibration (system.json), not a camera file"]),
        case(&format!("{projector} --image-sigma-px NaN"), &["--image-sigma-px", "NaN is not a positive"]),
        case(projector, &["plate_control.csv: the plate's control points are coplanar"]).with(
            "sim/plate_control.csv",
            "point,X,Y,Z\nC01,0,0,0\nC02,100,0,0\nC03,0,100,0\nC04,100,100,0\n",
        ),
        case("calibrate projector --camera camera.json --control sim/plate_control.csv --images sim --marker 10 --out sys.json",
            &["--marker", "\"10\" is not two comma-separated numbers"]),
        case("calibrate projector --camera camera.json --control sim/plate_control.csv --obs none.csv --out sys.json",
            &["none.csv", "No such file"]),
        case(&format!("{projector} --plots taken"), &["taken: cannot create"]).with("taken", ""),
        case("calibrate projector --camera camera.json --control sim/plate_control.csv --images small --out sys.json",
            &["small/p1.png: the image size differs from the expected one: 576 × 384 pixels"])
            .with("small/p1.png", resized("p1.png")),
        // calibrate system
        case(&format!("{system} --plots taken"), &["taken: cannot create"]).with("taken", ""),
        // scan: the 1st frame's cloud is not left behind when the 2nd fails.
        case(&format!("{scan} --host"), &["frame f2: the image is 576 × 384 pixels"])
            .with("frames/f1.png", image_bytes("p1.png"))
            .with("frames/f2.png", resized("p2.png")),
        case(scan, &["frame f2: the image is 576 × 384 pixels"])
            .with("frames/f1.png", image_bytes("p1.png"))
            .with("frames/f2.png", resized("p2.png")),
        // The observations measured from images are written before the calibration fails
        // (here on its output, a directory): they must not stay behind.
        case(
            &format!(
                "calibrate projector --camera camera.json --images {} --only p \
                 --control sim/plate_control.csv --out sysdir",
                images_parent().join("images").display()
            ),
            &["sysdir: cannot write: it is a directory"],
        )
        .with("sysdir/keep", ""),
        // measure
        case("measure none.png --out m.csv", &["none.png", "No such file"]),
        case("measure fake.png --out m.csv", &["fake.png", "not a PNG, TIFF or JPEG image"]).with("fake.png", "text"),
        case("measure float.tif --out m.csv", &["float.tif", "sample format is not supported"])
            .with("float.tif", float_tiff()),
        case("measure fake.png --out m.csv --tolerance -1", &["--tolerance", "-1 is not a positive"]),
        // bench, bench-measure
        case("bench-measure --repeats 0", &["--repeats", "0 is not in 1..=100"]),
        case("bench --images 4000000000", &["--images", "4000000000"]),
        case("bench --targets 1", &["--targets", "1 is not in 4..=100000"]),
        // device
        case("device upload none.json", &["none.json", "No such file"]),
        case("device upload big.json", &["big.json: 1400 projector rays", "more than the device holds: 1320 central rays"])
            .with("big.json", oversized_system()),
        case("device upload system.json --near 2000 --far 1500", &["--near 2000 mm must be less than --far 1500 mm"]),
        case("device upload system.json --near 500 --far 1500 --identify-cell 0", &["--identify-cell", "0 is not a positive"]),
        case("device stream --system system.json --simulate 4000000000 --out s.ply", &["--simulate", "4000000000"]),
        case("device stream --system system.json --obs none.csv --out s.ply", &["none.csv", "No such file"]),
        // The stream went through, but its CSV cannot be written: the PLY is not left alone.
        case("device stream --system system.json --simulate 2 --out s.ply --csv nodir/s.csv", &["nodir/s.csv", "cannot write"]),
        case("device --qemu=none.elf info", &["none.elf"]),
        // export
        case("export opencv --camera none.json --out c.yml", &["none.json", "No such file"]),
        case("export opencv --system camera.json --out c.yml", &["camera.json", "format \"deltaz.camera/1\", expected \"deltaz.system/2\""]),
        case("export opencv --camera camera.json --out nodir/c.yml", &["nodir/c.yml", "cannot write"]),
        // demo
        case("demo --out sim/camera_obs.csv", &["sim/camera_obs.csv"]),
    ]
}

#[test]
fn every_command_refuses_bad_input_cleanly() {
    let cases = cases();
    assert!(cases.len() >= 40, "{} cases", cases.len());
    let root = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for (index, case) in cases.iter().enumerate() {
        let dir = root.path().join(format!("case{index}"));
        copy_dir(fixture(), &dir);
        for (name, text) in &case.files {
            std::fs::create_dir_all(dir.join(name).parent().unwrap()).unwrap();
            std::fs::write(dir.join(name), text).unwrap();
        }
        let before = snapshot(&dir);
        let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
            .args(&case.args)
            .current_dir(&dir)
            .env("RUST_BACKTRACE", "1")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        let mut problems = Vec::new();
        if out.status.code() != Some(1) {
            problems.push(format!("exit {:?}", out.status.code()));
        }
        let errors = stderr.lines().filter(|l| l.starts_with("error: ")).count();
        if errors != 1 || stderr.contains("panicked") || stderr.contains("backtrace") {
            problems.push("not one clean error".to_owned());
        }
        problems.extend(
            case.expect
                .iter()
                .filter(|e| !stderr.contains(*e))
                .map(|e| format!("lacks {e:?}")),
        );
        if snapshot(&dir) != before {
            problems.push("files created or changed".to_owned());
        }
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}\n    {}",
                case.args.join(" "),
                problems.join(", "),
                stderr.trim()
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}

/// Input the commands used to take wrongly or silently, now taken as it should be: each case
/// exits 0 and `check` finds nothing wrong in (its directory, stdout, stderr).
struct Accepted {
    files: Vec<(&'static str, Vec<u8>)>,
    args: &'static str,
    check: fn(&Path, &str, &str) -> Vec<String>,
}

/// `what` appears in `text`, or a problem saying it does not.
fn has(text: &str, what: &str) -> Vec<String> {
    if text.contains(what) {
        Vec::new()
    } else {
        vec![format!("lacks {what:?}")]
    }
}

fn accepted() -> Vec<Accepted> {
    vec![
        // A points CSV of reconstruct over several images (the same ray in each), against the
        // PLY of the same run: every point matched to itself.
        Accepted {
            files: Vec::new(),
            args: "compare --reconstructed multi.csv --reference multi.ply",
            check: |_, out, _| {
                let mut p = has(out, "MSE (n-1 std of residuals): 0.0000 0.0000 0.0000 mm");
                p.extend(has(out, "2:"));
                p
            },
        },
        // --quiet: nothing on stderr but warnings (the device's upload said so before).
        Accepted {
            files: vec![("frames/f1.png", image_bytes("p1.png"))],
            args: "scan frames --system system.json --near 1600 --far 1900 --out clouds --quiet",
            check: |_, _, err| {
                (err.lines().filter(|l| !l.starts_with("warning: ")))
                    .map(|l| format!("prints {l:?}"))
                    .collect()
            },
        },
        // An uncalibrated camera (the start of a calibration) exported with a warning.
        Accepted {
            files: Vec::new(),
            args: "export opencv --camera sim/camera_init.json --out c.yml",
            check: |_, _, err| has(err, "warning: sim/camera_init.json: not calibrated"),
        },
        // The plots of calibrate system are the system adjustment's: its plate images, not the
        // field images of the bundle adjustment that started it.
        Accepted {
            files: Vec::new(),
            args: "calibrate system --init camera.json --camera-obs sim/camera_obs.csv \
                   --camera-control sim/camera_control.csv --control sim/plate_control.csv \
                   --obs sim/plate_obs.csv --out all.json --plots plots",
            check: |dir, _, _| {
                let svg = std::fs::read_to_string(dir.join("plots/residual_vectors.svg"));
                let svg = svg.unwrap_or_default();
                let mut p = has(&svg, "p1: RMS");
                if svg.contains("s1: RMS") {
                    p.push("draws the field images".to_owned());
                }
                p
            },
        },
        // The polarity flags every measuring command takes.
        Accepted {
            files: Vec::new(),
            args: "measure sim_p1.png --bright --out m.csv",
            check: |dir, _, _| {
                let csv = std::fs::read_to_string(dir.join("m.csv")).unwrap_or_default();
                if csv.lines().count() > 100 {
                    Vec::new()
                } else {
                    vec![format!("{} lines measured", csv.lines().count())]
                }
            },
        },
    ]
}

#[test]
fn commands_take_what_they_used_to_refuse_or_ignore() {
    let root = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for (index, case) in accepted().iter().enumerate() {
        let dir = root.path().join(format!("accepted{index}"));
        copy_dir(fixture(), &dir);
        std::fs::write(dir.join("sim_p1.png"), image_bytes("p1.png")).unwrap();
        for (name, bytes) in &case.files {
            std::fs::create_dir_all(dir.join(name).parent().unwrap()).unwrap();
            std::fs::write(dir.join(name), bytes).unwrap();
        }
        let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
            .args(case.args.split_whitespace())
            .current_dir(&dir)
            .output()
            .unwrap();
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr),
        );
        let mut problems = (case.check)(&dir, &stdout, &stderr);
        if !out.status.success() {
            problems.insert(0, format!("exit {:?}", out.status.code()));
        }
        if !problems.is_empty() {
            failures.push(format!(
                "{}: {}\n    {}",
                case.args,
                problems.join(", "),
                stderr.trim()
            ));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A reader that closes the pipe (`deltaz ... | head`) ends the command as it ends Unix tools:
/// by SIGPIPE, with nothing on stderr, never a panic about "failed printing to stdout".
#[cfg(unix)]
#[test]
fn a_closed_stdout_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(["device", "info"])
        .env("RUST_BACKTRACE", "1")
        .stdout(writer)
        .output()
        .unwrap();
    // SIGPIPE is signal 13 on Linux and the BSDs.
    assert_eq!(out.status.signal(), Some(13), "{:?}", out.status);
    assert!(
        out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
