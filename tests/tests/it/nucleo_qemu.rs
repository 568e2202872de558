//! The real board's firmware, unmodified (the `nucleo_f401re` ELF), on QEMU's `netduinoplus2`
//! (an STM32F405: the same Cortex-M4F, USART2 at the F401's address and interrupt, on QEMU's
//! second serial port), through `deltaz device --port` and the client's serial link: it boots
//! although the emulator models neither the clock tree nor the flash interface (every wait is
//! bounded; the clock falls back to the internal oscillator and `device info` says so),
//! answers Info and Stats, answers bad frames, refuses an upload its flash cannot store while
//! keeping what it held, and a stream then says the device holds no calibration.

use deltaz_host::link::{Device, DeviceError, Serial, Transport};
use deltaz_shared::protocol::{ClockSource, ErrorCode, PROTOCOL_VERSION};
use deltaz_tests::pattern::pattern_rig;
use deltaz_tests::{deltaz_binary, nucleo_elf};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

/// QEMU running the board's ELF, its USART2 on a pty.
struct Board {
    child: Child,
    pty: String,
}

impl Board {
    fn start() -> Self {
        let mut child = Command::new("qemu-system-arm")
            .args([
                "-machine",
                "netduinoplus2",
                "-nographic",
                "-monitor",
                "none",
            ])
            .args(["-serial", "null", "-serial", "pty", "-kernel"])
            .arg(nucleo_elf())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("qemu-system-arm must be installed (apt-get install qemu-system-arm)");
        // QEMU names the pty it made on stdout: "char device redirected to /dev/pts/N (label
        // serial1)", then prints nothing more (-nographic, no monitor).
        let mut pty = None;
        for line in BufReader::new(child.stdout.take().unwrap()).lines().take(5) {
            let line = line.unwrap_or_default();
            if let Some(at) = line.find("/dev/pts/") {
                pty = line[at..].split_whitespace().next().map(str::to_owned);
                break;
            }
        }
        let pty = pty.expect("QEMU names the pty of USART2");
        Self { child, pty }
    }

    /// `deltaz device --port PTY ARGS...`.
    fn deltaz(&self, args: &[&str]) -> Output {
        Command::new(deltaz_binary())
            .args(["device", "--port", &self.pty, "--timeout-ms", "5000"])
            .args(args)
            .output()
            .expect("run deltaz")
    }

    /// The client over the same serial port.
    fn client(&self) -> Device<Serial> {
        Device::new(Serial::open(&self.pty, 2_000_000).expect("open the pty"))
            .with_timeout(Duration::from_secs(5))
    }
}

impl Drop for Board {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn nucleo_image_serves_on_an_emulated_stm32f4() {
    let board = Board::start();

    // Info through the command line: the protocol, the capacity, no calibration, and the clock
    // it fell back to (the emulator starts neither the external clock nor the PLL).
    let info = board.deltaz(&["info", "--json"]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        info.status.success(),
        "{text} {}",
        String::from_utf8_lossy(&info.stderr)
    );
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["protocol"], PROTOCOL_VERSION, "{json}");
    assert_eq!(json["ray_capacity"], 1320, "{json}");
    assert!(json["calibration"].is_null(), "{json}");
    assert_eq!(json["clock"]["hz"], 16_000_000, "{json}");
    assert_eq!(json["clock"]["source"], "internal", "{json}");
    let plain = board.deltaz(&["info"]);
    let plain = String::from_utf8_lossy(&plain.stdout);
    assert!(
        plain.contains("clock: 16.0 MHz from the internal oscillator alone"),
        "{plain}"
    );

    // Stats and bad frames through the client's serial link (what `--port` uses).
    let mut device = board.client();
    let info = device.info().expect("info");
    assert_eq!(
        info.clock.map(|c| c.source),
        Some(ClockSource::Internal),
        "{info:?}"
    );
    let before = device.stats().expect("stats");
    let mut line = device.into_transport();
    line.send(&[0x00, 0x07, 0x41, 0x42, 0x43, 0x00, 0x05, 0x99, 0x00])
        .expect("send noise");
    let mut answer = vec![0u8; 64];
    let n = line
        .recv(&mut answer, Duration::from_secs(5))
        .expect("the device answers the noise");
    assert!(n > 0, "an answer to a bad frame");
    let mut device = Device::new(line).with_timeout(Duration::from_secs(5));
    let after = device.stats().expect("stats");
    assert!(
        after.bad_frames >= before.bad_frames + 2,
        "{before:?} {after:?}"
    );

    // An upload: the emulated flash does not store, so the store refuses it cleanly and the
    // device keeps what it held (nothing).
    let refused = device.upload(&pattern_rig(), 0xF401).unwrap_err();
    assert!(
        matches!(refused, DeviceError::Device(ErrorCode::Storage)),
        "{refused}"
    );
    let info = device.info().expect("info after the refused upload");
    assert_eq!(info.calibration, None);
    drop(device);

    // A stream needs a calibration the device holds: it says so.
    let dir = std::env::temp_dir().join(format!("deltaz-nucleo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let obs = dir.join("obs.csv");
    std::fs::write(&obs, "image,point,col,row,kind\np1,1,100.5,200.25,dot\n").unwrap();
    let stream = board.deltaz(&["stream", "--obs", obs.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&stream.stderr);
    assert!(!stream.status.success());
    assert!(stderr.contains("holds no calibration"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}
