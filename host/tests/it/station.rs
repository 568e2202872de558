//! `deltaz station` through the binary and plain HTTP: what it refuses (names that would leave
//! the data folder, requests it does not serve, other sites), and what it survives (the source
//! gone, frames without dots, a device that stops answering, a second station on the same data
//! folder, a camera that is not there), each shown in its status while it keeps serving. The
//! helpers here (the fixture, a station process, HTTP) serve the browser test too.

use crate::cli::paper_rig;
use deltaz_host::simulate::back::{BackModel, Deformity, Pose};
use deltaz_host::simulate::back_frames::render_back;
use deltaz_host::simulate::images::{true_rig, ImageSpec};
use deltaz_host::simulate::objects::{object_dots, object_frame, Object};
use deltaz_host::simulate::true_camera;
use nalgebra::Vector3;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// The station's fixture: a calibrated system of the paper rig (`system.json`, with its
/// covariance), rendered frames of a back (`frames/`), of the back before a wall
/// (`walled/`), of a flat board (`plane/`) and
/// black frames without dots (`empty/`), all at the rig's 768 × 512 pixels, and the subject's
/// depth range (near, far) in mm.
pub struct Fixture {
    pub dir: PathBuf,
    pub near: f64,
    pub far: f64,
}

pub fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("station_fixture");
        deltaz_testkit::fixture(&dir.with_extension("lock"), move || {
            // The image noise of the rendered frames' dots, so that the calibration's σ0 of the
            // dots (the points' own share) is theirs.
            let scenario = paper_rig(&dir, 0.2, 3, &["--quiet"]);
            let (grid, _) = true_camera(&scenario);
            let rig = true_rig(&scenario);
            let render = |folder: &str, objects: &[Object]| {
                std::fs::create_dir_all(dir.join(folder)).unwrap();
                for (k, object) in objects.iter().enumerate() {
                    let dots = object_dots(&rig, object);
                    object_frame(&rig, &dots, 100 + k as u64)
                        .save(dir.join(folder).join(format!("f{k:02}.png")))
                        .unwrap();
                }
            };
            // A scoliotic back standing 1.5 m from the camera, swayed a little from frame to frame,
            // rendered through the paper rig (440 rays: the in-process device holds them).
            let spec = ImageSpec::default();
            std::fs::create_dir_all(dir.join("frames")).unwrap();
            for k in 0..6u32 {
                let s = f64::from(k % 3) - 1.0;
                let model = BackModel::standing(Deformity::thoracic()).with_pose(Pose {
                    rotation: Vector3::new(0.0, 0.004 * s, 0.0),
                    translation: Vector3::new(2.0 * s, 0.0, 1.5 * s),
                });
                let label = format!("f{k:02}");
                render_back(&rig, &label, &model, &spec, 100 + u64::from(k))
                    .image
                    .save_png(&dir.join("frames").join(format!("{label}.png")), spec.depth)
                    .unwrap();
            }
            // The same back 200 mm aside, before a wall 140 mm behind it, within the working depth.
            std::fs::create_dir_all(dir.join("walled")).unwrap();
            for k in 0..3u64 {
                let model = BackModel {
                    backdrop: Some(WALL_MM),
                    ..BackModel::standing(Deformity::thoracic())
                }
                .with_pose(Pose {
                    rotation: Vector3::zeros(),
                    translation: Vector3::new(-200.0, 0.0, 0.0),
                });
                let label = format!("w{k:02}");
                render_back(&rig, &label, &model, &spec, 200 + k)
                    .image
                    .save_png(&dir.join("walled").join(format!("{label}.png")), spec.depth)
                    .unwrap();
            }
            let plane: Vec<Object> = (0..3)
                .map(|k| Object::Plane {
                    depth: 1500.0 + 5.0 * f64::from(k),
                    tilt: 0.1,
                })
                .collect();
            render("plane", &plane);
            std::fs::create_dir_all(dir.join("empty")).unwrap();
            for k in 0..2 {
                image::GrayImage::new(grid.width, grid.height)
                    .save(dir.join("empty").join(format!("e{k}.png")))
                    .unwrap();
            }
            Fixture {
                dir,
                near: 1420.0,
                far: 1650.0,
            }
        })
    })
}

/// The distance from the camera of the wall behind the back in the fixture's `walled/` frames
/// (mm): within the subject's depth range.
const WALL_MM: f64 = 1640.0;

/// A station process, ended when dropped.
pub struct Station {
    pub child: Child,
    pub addr: SocketAddr,
}

impl Drop for Station {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `deltaz station --system ... --replay REPLAY --near --far --listen 127.0.0.1:0 --data DATA`
/// with `extra` arguments; waits for its address.
pub fn station(replay: &Path, data: &Path, extra: &[&str]) -> Station {
    station_with(&fixture().dir.join("system.json"), replay, data, extra)
}

/// [`station`] with another system.json.
pub fn station_with(system: &Path, replay: &Path, data: &Path, extra: &[&str]) -> Station {
    let f = fixture();
    let mut child = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .arg("station")
        .arg("--system")
        .arg(system)
        .arg("--replay")
        .arg(replay)
        .args([
            "--fps",
            "10",
            "--near",
            &f.near.to_string(),
            "--far",
            &f.far.to_string(),
        ])
        .args(["--listen", "127.0.0.1:0", "--data"])
        .arg(data)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .trim()
        .strip_prefix("station at http://")
        .and_then(|a| a.strip_suffix('/'))
        .unwrap_or_else(|| {
            let mut err = String::new();
            let _ = child.stderr.take().unwrap().read_to_string(&mut err);
            panic!("no address from the station: {line:?} {err}")
        })
        .parse()
        .unwrap();
    Station { child, addr }
}

/// One HTTP/1.1 request: the status and the body.
pub fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> (u16, String) {
    let mut stream = TcpStream::connect(addr).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let mut request = format!("{method} {path} HTTP/1.1\r\nConnection: close\r\n");
    if !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("host")) {
        request += &format!("Host: {addr}\r\n");
    }
    for (k, v) in headers {
        request += &format!("{k}: {v}\r\n");
    }
    request += &format!("Content-Length: {}\r\n\r\n{body}", body.len());
    stream.write_all(request.as_bytes()).unwrap();
    let mut response = Vec::new();
    stream.read_to_end(&mut response).unwrap();
    let text = String::from_utf8_lossy(&response).into_owned();
    let status = text[9..12].parse().unwrap();
    let body = text
        .split_once("\r\n\r\n")
        .map_or("", |(_, b)| b)
        .to_owned();
    (status, body)
}

/// GET `path` as JSON (status 200).
pub fn get_json(addr: SocketAddr, path: &str) -> serde_json::Value {
    let (status, body) = http(addr, "GET", path, &[], "");
    assert_eq!(status, 200, "GET {path}: {body}");
    serde_json::from_str(&body).unwrap()
}

/// POST JSON `body` to `path` from the station's own page: status and JSON.
pub fn post_json(addr: SocketAddr, path: &str, body: &str) -> (u16, serde_json::Value) {
    let origin = format!("http://{addr}");
    let headers = [
        ("Content-Type", "application/json"),
        ("Origin", origin.as_str()),
    ];
    let (status, text) = http(addr, "POST", path, &headers, body);
    (
        status,
        serde_json::from_str(&text).unwrap_or(serde_json::Value::Null),
    )
}

/// Polls `/api/status` until `done` holds (at most `seconds`), returning that status.
pub fn wait_status(
    addr: SocketAddr,
    seconds: u64,
    what: &str,
    done: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let start = Instant::now();
    loop {
        let status = get_json(addr, "/api/status");
        if done(&status) {
            return status;
        }
        assert!(
            start.elapsed() < Duration::from_secs(seconds),
            "waited {seconds} s for {what}: {status:#}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

pub fn points(status: &serde_json::Value) -> u64 {
    status["live"]["counts"]["points"].as_u64().unwrap_or(0)
}

/// Copies the files of `from` into a new folder `to`.
pub fn copy_frames(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, to.join(path.file_name().unwrap())).unwrap();
    }
}

#[test]
fn names_and_requests_it_does_not_serve_are_refused() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let s = station(&f.dir.join("frames"), &data, &[]);
    wait_status(s.addr, 60, "points", |st| points(st) > 0);
    // A session to aim at.
    let (code, session) = post_json(s.addr, "/api/capture", r#"{"subject":"s1"}"#);
    assert_eq!(code, 200, "{session}");
    let name = session["name"].as_str().unwrap().to_owned();
    let good = format!("/sessions/s1/{name}/report.html");
    assert_eq!(http(s.addr, "GET", &good, &[], "").0, 200);
    // Traversal through every name the page sends: refused before a path is built.
    for path in [
        format!("/sessions/..%2F..%2F..%2Fetc/{name}/report.html"),
        format!("/sessions/s1/..%2F{name}/report.html"),
        format!("/sessions/s1/{name}/..%2Fsession.json"),
        format!("/sessions/s1/{name}/clouds%2Ff00.ply"),
        "/sessions/s1/..%2F..%2F/passwd".to_owned(),
        "/api/subjects/..%2F..%2Fetc/sessions".to_owned(),
        format!("/api/compare?subject=s1&before=..%2F{name}&after={name}"),
        format!("/api/compare?subject=..&before={name}&after={name}"),
    ] {
        let (code, body) = http(s.addr, "GET", &path, &[], "");
        assert_eq!(code, 400, "{path}: {body}");
        assert!(body.contains("refused"), "{path}: {body}");
    }
    for subject in ["../outside", "..", "a/b", "/tmp/x", "-x", ".staging-1"] {
        let body = serde_json::json!({ "subject": subject }).to_string();
        let (code, answer) = post_json(s.addr, "/api/capture", &body);
        assert_eq!(code, 400, "{subject}: {answer}");
        assert!(
            answer["error"].as_str().unwrap().contains("refused"),
            "{answer}"
        );
    }
    assert!(!dir.path().join("outside").exists());
    let mut inside: Vec<String> = std::fs::read_dir(&data)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    inside.sort();
    assert_eq!(inside, ["s1"], "only the good subject, no staging left");
    // Paths and methods it does not serve.
    for (method, path, code) in [
        ("GET", "/../../etc/passwd", 404),
        ("GET", "/.env", 404),
        ("GET", "/sessions/s1", 404),
        ("DELETE", "/", 405),
        ("PUT", "/api/capture", 405),
        ("GET", "/api/capture", 405),
    ] {
        let (got, body) = http(s.addr, method, path, &[], "");
        assert_eq!(got, code, "{method} {path}: {body}");
        assert!(!body.contains("root:"), "{body}");
    }
    // Another site: through a name that resolves here, or a form posted from its page.
    let (code, body) = http(
        s.addr,
        "GET",
        "/api/status",
        &[("Host", "evil.example")],
        "",
    );
    assert_eq!(
        (code, body.contains("is not this station")),
        (403, true),
        "{body}"
    );
    let cross = [
        ("Content-Type", "application/json"),
        ("Origin", "http://evil.example"),
    ];
    let (code, body) = http(
        s.addr,
        "POST",
        "/api/capture",
        &cross,
        r#"{"subject":"s2"}"#,
    );
    assert_eq!(
        (code, body.contains("not from this station's page")),
        (403, true),
        "{body}"
    );
    let plain = [("Content-Type", "text/plain")];
    assert_eq!(
        http(
            s.addr,
            "POST",
            "/api/capture",
            &plain,
            r#"{"subject":"s2"}"#
        )
        .0,
        415
    );
    assert!(!data.join("s2").exists());
    // The page runs only its own script.
    let mut stream = TcpStream::connect(s.addr).unwrap();
    write!(
        stream,
        "GET / HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
        s.addr
    )
    .unwrap();
    let mut head = String::new();
    stream.read_to_string(&mut head).unwrap();
    assert!(
        head.contains("content-security-policy: default-src 'none'; script-src 'self'"),
        "{head}"
    );
}

#[test]
fn without_listen_it_serves_this_computer_only() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .args(["station", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(help.contains("[default: 127.0.0.1:8470]"), "{help}");
    // A missing camera: a clear error before anything listens, no data folder left.
    let out = Command::new(env!("CARGO_BIN_EXE_deltaz"))
        .arg("station")
        .arg("--system")
        .arg(f.dir.join("system.json"))
        .args([
            "--camera",
            "/dev/video-not-here",
            "--near",
            "1000",
            "--far",
            "2000",
        ])
        .arg("--data")
        .arg(dir.path().join("data"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with(
            "error: /dev/video-not-here: cannot open the camera: No such file or directory"
        ),
        "{err}"
    );
    assert!(out.stdout.is_empty());
}

#[test]
fn the_source_gone_is_shown_and_nothing_captured_is_lost() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let replay = dir.path().join("replay");
    copy_frames(&f.dir.join("frames"), &replay);
    let data = dir.path().join("data");
    let s = station(&replay, &data, &[]);
    wait_status(s.addr, 60, "points", |st| points(st) > 0);
    let (code, session) = post_json(s.addr, "/api/capture", r#"{"subject":"s1"}"#);
    assert_eq!(code, 200, "{session}");
    let folder = data.join("s1").join(session["name"].as_str().unwrap());
    let before: Vec<Vec<u8>> = [
        "session.json",
        "analysis.json",
        "report.html",
        "centroids.csv",
    ]
    .iter()
    .map(|n| std::fs::read(folder.join(n)).unwrap())
    .collect();
    std::fs::remove_dir_all(&replay).unwrap();
    let status = wait_status(s.addr, 30, "the source gone", |st| {
        st["status"]["source"]["ok"] == false
    });
    let text = status["status"]["source"]["text"].as_str().unwrap();
    assert!(
        text.contains("replay") && text.contains("trying again"),
        "{text}"
    );
    // Still serving: the page, its status, the session and its files, unchanged.
    assert_eq!(http(s.addr, "GET", "/", &[], "").0, 200);
    let sessions = get_json(s.addr, "/api/subjects/s1/sessions");
    assert_eq!(sessions.as_array().unwrap().len(), 1);
    for (n, bytes) in [
        "session.json",
        "analysis.json",
        "report.html",
        "centroids.csv",
    ]
    .iter()
    .zip(&before)
    {
        assert_eq!(&std::fs::read(folder.join(n)).unwrap(), bytes, "{n}");
    }
    // The source back: frames again.
    let seq = status["live"]["seq"].as_u64().unwrap();
    copy_frames(&f.dir.join("frames"), &replay);
    wait_status(s.addr, 30, "the source back", |st| {
        st["status"]["source"]["ok"] == true && st["live"]["seq"].as_u64().unwrap() > seq + 2
    });
}

#[test]
fn frames_without_dots_are_shown_as_such() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let s = station(&f.dir.join("empty"), &dir.path().join("data"), &[]);
    let status = wait_status(s.addr, 60, "a frame", |st| {
        st["live"]["seq"].as_u64() > Some(1)
    });
    assert_eq!(status["live"]["counts"]["dots"], 0);
    let notice = status["live"]["notice"].as_str().unwrap();
    assert!(notice.starts_with("no dots in this frame"), "{notice}");
    let surface = wait_status(s.addr, 10, "the surface", |st| !st["surface"].is_null());
    assert_eq!(surface["surface"]["error"], "no frame with points yet");
    let (code, answer) = post_json(s.addr, "/api/capture", r#"{"subject":"s1"}"#);
    assert_eq!(code, 400);
    assert_eq!(
        answer["error"],
        "nothing to capture: no frame with points yet"
    );
    assert!(!dir.path().join("data").join("s1").exists());
    let (code, answer) = post_json(s.addr, "/api/plane-check", "{}");
    assert_eq!(code, 400);
    assert!(
        answer["error"]
            .as_str()
            .unwrap()
            .starts_with("no frame with 30 points"),
        "{answer}"
    );
}

#[test]
fn a_device_that_stops_answering_is_shown_and_the_station_keeps_running() {
    use deltaz_host::link::{InProcess, Transport};
    use serialport::SerialPort;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    // A device on a serial line (a pty): the firmware's logic behind the line's other end,
    // answering until `silent`.
    let (mut line, device_end) = serialport::TTYPort::pair().unwrap();
    let port = device_end.name().unwrap();
    let (silent, done) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicBool::new(false)),
    );
    let pump = {
        let (silent, done) = (silent.clone(), done.clone());
        std::thread::spawn(move || {
            line.set_timeout(Duration::from_millis(2)).unwrap();
            let mut device = InProcess::new();
            let (mut buf, mut out) = ([0u8; 4096], [0u8; 4096]);
            while !done.load(Ordering::Relaxed) {
                let n = line.read(&mut buf).unwrap_or(0);
                if silent.load(Ordering::Relaxed) {
                    continue;
                }
                device.send(&buf[..n]).unwrap();
                let m = device.recv(&mut out, Duration::ZERO).unwrap();
                line.write_all(&out[..m]).unwrap();
            }
        })
    };
    let s = station(
        &f.dir.join("frames"),
        &dir.path().join("data"),
        &["--port", &port, "--baud", "115200", "--timeout-ms", "200"],
    );
    let answering = wait_status(s.addr, 60, "points through the line", |st| points(st) > 0);
    assert_eq!(answering["status"]["device"]["health"]["text"], "answering");
    let fingerprint = answering["status"]["device"]["fingerprint"]
        .as_str()
        .unwrap()
        .to_owned();
    assert_eq!(fingerprint.len(), 16);
    silent.store(true, Ordering::Relaxed);
    let status = wait_status(s.addr, 30, "the device silent", |st| {
        st["status"]["device"]["health"]["ok"] == false
    });
    let text = status["status"]["device"]["health"]["text"]
        .as_str()
        .unwrap();
    assert!(
        text.contains("did not answer") || text.contains("no valid answer"),
        "{text}"
    );
    assert!(text.contains("trying again"), "{text}");
    // Frames still arrive, without points; the page and the calibration still answer.
    let seq = status["live"]["seq"].as_u64().unwrap();
    let later = wait_status(s.addr, 30, "frames while silent", |st| {
        st["live"]["seq"].as_u64().unwrap() > seq + 1
    });
    assert_eq!(points(&later), 0);
    assert_eq!(
        later["status"]["device"]["fingerprint"],
        fingerprint.as_str()
    );
    assert_eq!(
        get_json(s.addr, "/api/calibration")["fingerprint"],
        fingerprint.as_str()
    );
    // Answering again: points again.
    silent.store(false, Ordering::Relaxed);
    let back = wait_status(s.addr, 30, "the device back", |st| {
        st["status"]["device"]["health"]["ok"] == true && points(st) > 0
    });
    assert!(
        back["status"]["device"]["resent"].as_u64().unwrap() > 0,
        "{back:#}"
    );
    done.store(true, Ordering::Relaxed);
    drop(s);
    pump.join().unwrap();
    drop(device_end);
}

#[test]
fn two_stations_on_one_data_folder_keep_every_session_whole() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let stations = [
        station(&f.dir.join("frames"), &data, &[]),
        station(&f.dir.join("frames"), &data, &[]),
    ];
    for s in &stations {
        wait_status(s.addr, 60, "points", |st| points(st) > 0);
    }
    // Three captures of one subject at each station at once: some in the same second.
    let addrs: Vec<SocketAddr> = stations.iter().map(|s| s.addr).collect();
    let captures: Vec<_> = (0..6)
        .map(|k| {
            let addr = addrs[k % 2];
            std::thread::spawn(move || post_json(addr, "/api/capture", r#"{"subject":"s1"}"#))
        })
        .collect();
    let mut names = Vec::new();
    for c in captures {
        let (code, session) = c.join().unwrap();
        assert_eq!(code, 200, "{session}");
        names.push(session["name"].as_str().unwrap().to_owned());
    }
    names.sort();
    names.dedup();
    assert_eq!(names.len(), 6, "{names:?}");
    let listed = get_json(addrs[0], "/api/subjects/s1/sessions");
    let listed: Vec<&str> = listed
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert_eq!(listed, names);
    for name in &names {
        let folder = data.join("s1").join(name);
        let session: serde_json::Value =
            serde_json::from_slice(&std::fs::read(folder.join("session.json")).unwrap()).unwrap();
        assert_eq!(session["name"], name.as_str());
        let analysis = deltaz_host::io::analysis_file::read_report(&folder.join("analysis.json"));
        assert!(analysis.is_ok(), "{name}: {analysis:?}");
        for cloud in session["frames"].as_array().unwrap() {
            let cloud = cloud["cloud"].as_str().unwrap();
            assert!(deltaz_host::io::ply::read_cloud(&folder.join(cloud)).is_ok());
        }
    }
    let left: Vec<_> = std::fs::read_dir(&data)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, ["s1"], "no staging folder left");
}

/// The plane check on `system` with the flat board's frames.
fn plane_check(system: &Path) -> serde_json::Value {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let s = station_with(system, &f.dir.join("plane"), &dir.path().join("data"), &[]);
    wait_status(s.addr, 60, "points", |st| points(st) > 100);
    let (code, check) = post_json(s.addr, "/api/plane-check", "{}");
    assert_eq!(code, 200, "{check}");
    check
}

#[test]
fn the_plane_check_tells_a_sound_calibration_from_a_bent_one() {
    let f = fixture();
    // The floor holds the calibration's own covariance (its camera prior is the nominal camera
    // file's, loose) besides the image noise: a sound calibration's board stays below it.
    let sound = plane_check(&f.dir.join("system.json"));
    let ratio = sound["ratio"].as_f64().unwrap();
    assert!((0.3..1.25).contains(&ratio), "{sound:#}");
    assert_eq!(sound["holds"], true);
    assert!(sound["verdict"]
        .as_str()
        .unwrap()
        .starts_with("the calibration holds"));
    // The same calibration with a wrong radial distortion bends the board.
    let (mut file, _) =
        deltaz_host::io::system_file::SystemFile::load(&f.dir.join("system.json")).unwrap();
    file.content.camera.inner.k1 += 3e-4;
    let bent = deltaz_host::io::system_file::SystemFile::new(file.content).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bent.json");
    std::fs::write(&path, serde_json::to_string(&bent).unwrap()).unwrap();
    let check = plane_check(&path);
    assert_eq!(check["holds"], false, "{check:#}");
    assert!(check["ratio"].as_f64().unwrap() > 1.5, "{check:#}");
    assert!(check["verdict"]
        .as_str()
        .unwrap()
        .starts_with("calibrate again"));
    let s = station(&f.dir.join("plane"), &dir.path().join("data"), &[]);
    let facts = get_json(s.addr, "/api/calibration");
    assert_eq!(facts["rays"], 440);
    let sigma = facts["sigma0_px"]["dots"].as_f64().unwrap();
    assert!(
        (0.1..0.4).contains(&sigma),
        "the simulated 0.2 px: {facts:#}"
    );
}

/// The back, standing 200 mm left of the camera's axis, before a wall within the working depth
/// (beside the back the wall is larger than it): the live surface is the back's, and its notes
/// name the wall left out in each frame (by its label), where it lies and how far beyond the
/// back.
#[test]
fn a_wall_behind_the_back_is_named_on_the_surface() {
    let f = fixture();
    let dir = tempfile::tempdir().unwrap();
    let s = station(&f.dir.join("walled"), &dir.path().join("data"), &[]);
    let status = wait_status(s.addr, 60, "the surface", |st| {
        st["surface"]["frames"].as_u64() == Some(3)
    });
    let surface = &status["surface"];
    let notes: Vec<&str> = surface["notes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap())
        .collect();
    let walls: Vec<&&str> = notes
        .iter()
        .filter(|n| n.contains("a plane larger than the back left out"))
        .collect();
    assert_eq!(walls.len(), 3, "one a frame: {surface:#}");
    for wall in walls {
        // "... points about (x, y, z) in the camera system, D mm beyond the back; ..."
        let z: f64 = wall
            .split(", ")
            .find_map(|p| p.strip_suffix(") in the camera system"))
            .unwrap()
            .parse()
            .unwrap();
        let beyond: f64 = wall
            .split(" in the camera system, ")
            .nth(1)
            .and_then(|r| r.split(" mm beyond").next())
            .unwrap()
            .parse()
            .unwrap();
        // The wall stands 140 mm behind the skin, 1,500 mm from the camera.
        assert!(wall.starts_with("frame w0"), "named by its label: {wall}");
        assert!((z + WALL_MM).abs() < 10.0, "{wall}");
        assert!((120.0..160.0).contains(&beyond), "{wall}");
    }
    assert!(surface["levels"].as_u64().unwrap() >= 5, "{surface:#}");
    // The points apart from the back counted: the back model's arms (the wall's are a plane's).
    assert!(surface["points_apart"].as_u64().unwrap() > 0, "{surface:#}");
}
