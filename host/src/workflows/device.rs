//! A session with the device: connecting as the command line says (a serial port, QEMU or the
//! firmware's logic in-process), its info, and making sure it holds a calibration (uploading
//! it where that is safe).

use crate::io::system_file::{SystemFile, SystemRig};
use crate::link::{Device, DeviceError, InProcess, Qemu, Serial, Transport};
use crate::report::console::Output;
use anyhow::{bail, Context, Result};
use deltaz_firmware::server::IN_FLIGHT_BYTES;
use deltaz_shared::protocol::calibration::{IdentifyParams, IntersectionMethod};
use deltaz_shared::protocol::{CalibrationSummary, MAX_NONCENTRAL_RAYS, MAX_RAYS};
use deltaz_shared::rig::Method;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Which device to talk to.
#[derive(Debug, Clone)]
pub struct LinkArgs {
    /// A serial port; without it (and without `qemu`) the firmware's logic runs in-process.
    pub port: Option<String>,
    /// Baud rate of `port`.
    pub baud: u32,
    /// Start the firmware in QEMU (mps2-an386) from this ELF and talk to it over a pty.
    pub qemu: Option<PathBuf>,
    /// Response timeout.
    pub timeout: Duration,
    /// Text or one JSON object on stdout; status on stderr unless quiet.
    pub output: Output,
}

/// Whatever transport the arguments name.
pub type AnyDevice = Device<Box<dyn Transport>>;

/// Connect as `args` say.
pub fn connect(args: &LinkArgs) -> Result<AnyDevice> {
    let transport: Box<dyn Transport> = match (&args.port, &args.qemu) {
        (Some(_), Some(_)) => bail!("--port and --qemu exclude each other"),
        (Some(port), None) => {
            // A board receives the next request while it answers one (behind it in its receive
            // buffer, the rest in its RX ring; nothing holds the line): two requests in flight
            // within what it holds, `IN_FLIGHT_BYTES` (two 440-dot frames, not two of 512).
            let serial = Serial::open(port, args.baud)?;
            return Ok(Device::new(Box::new(serial) as Box<dyn Transport>)
                .with_timeout(args.timeout)
                .with_window(2)
                .with_in_flight_bytes(IN_FLIGHT_BYTES));
        }
        (None, Some(elf)) => {
            if !elf.exists() {
                bail!(
                    "no firmware at {} (cargo build -p deltaz-firmware --target \
                     thumbv7em-none-eabihf --release)",
                    elf.display()
                );
            }
            Box::new(Qemu::spawn(elf)?)
        }
        (None, None) => Box::new(InProcess::new()),
    };
    Ok(Device::new(transport).with_timeout(args.timeout))
}

/// `deltaz device ports`.
pub fn ports() -> Result<()> {
    let ports = crate::link::list_ports()?;
    if ports.is_empty() {
        println!("no serial ports");
    }
    for (path, what) in ports {
        println!("{path}\t{what}");
    }
    Ok(())
}

/// `deltaz device info` (`--json`: one JSON object on stdout).
pub fn info(args: &LinkArgs) -> Result<()> {
    let mut device = connect(args)?;
    let i = device.info()?;
    let [a, b, c] = i.firmware;
    if args.output.json {
        let calibration = i.calibration.map(|s| {
            serde_json::json!({
                "fingerprint": format!("{:016x}", s.fingerprint),
                "generation": s.generation,
                "rays": s.rays,
                "centroid_bits": s.centroid_bits,
                "camera_centre_mm": s.camera_centre,
                "method": method_name(s.method),
            })
        });
        let json = serde_json::json!({
            "firmware": format!("{a}.{b}.{c}"),
            "protocol": i.protocol,
            "ray_capacity": i.ray_capacity,
            "max_batch": i.max_batch,
            "max_frame": i.max_frame,
            "max_calibration": i.max_calibration,
            "calibration": calibration,
            "boot_error": i.boot_error.map(|e| e.to_string()),
            "clock": i.clock.map(|c| serde_json::json!({
                "hz": c.hz,
                "source": format!("{:?}", c.source).to_lowercase(),
                "text": c.source.to_string(),
            })),
        });
        println!("{json}");
        return Ok(());
    }
    println!("firmware {a}.{b}.{c}, protocol {}", i.protocol);
    println!(
        "capacity: {} rays, {} centroids per frame, frames up to {} bytes, calibration up to {} bytes",
        i.ray_capacity, i.max_batch, i.max_frame, i.max_calibration
    );
    match i.calibration {
        Some(s) => println!(
            "calibration {:016x} (generation {}): {} rays, centroids in 1/{} pixel, camera centre {:.3?} mm, intersection {}",
            s.fingerprint,
            s.generation,
            s.rays,
            1u32 << s.centroid_bits,
            s.camera_centre,
            method_name(s.method)
        ),
        None => println!("no calibration"),
    }
    if let Some(e) = i.boot_error {
        println!("the stored calibration failed to load at boot: {e}");
    }
    if let Some(c) = i.clock {
        println!("clock: {:.1} MHz from {}", f64::from(c.hz) / 1e6, c.source);
    }
    Ok(())
}

/// A system.json loaded for the device: the file (its frame), the rig and its fingerprint.
pub type LoadedSystem = (SystemFile, SystemRig, u64);

/// Load `system.json`: the rig and its fingerprint; refused when it has more rays than a
/// device holds ([`MAX_RAYS`]).
pub fn load_system(path: &Path) -> Result<LoadedSystem> {
    let (file, rig) = SystemFile::load(path)?;
    check_capacity(path, &rig)?;
    let fingerprint = file.fingerprint_u64()?;
    Ok((file, rig, fingerprint))
}

/// Refuses a system with more rays than a device holds ([`MAX_RAYS`], or
/// [`MAX_NONCENTRAL_RAYS`] for a non-central model whose rays carry offsets), saying what
/// would fit.
pub fn check_capacity(path: &Path, rig: &SystemRig) -> Result<()> {
    let rays = rig.projector_centred().rays();
    let noncentral = rays.iter().any(|r| r.offset != nalgebra::Vector3::zeros());
    let (capacity, kind) = if noncentral {
        (MAX_NONCENTRAL_RAYS, "non-central rays (with offsets)")
    } else {
        (MAX_RAYS, "central rays")
    };
    if rays.len() > capacity {
        bail!(
            "{}: {} projector rays, more than the device holds: {capacity} {kind} (a central \
             calibration holds up to {MAX_RAYS})",
            path.display(),
            rays.len()
        );
    }
    Ok(())
}

/// Upload `system` to `device` (with the parameters to identify unlabelled dots, if given) and
/// say so on stderr.
pub fn upload_to(
    device: &mut AnyDevice,
    link: &LinkArgs,
    (system, rig, fingerprint): (&Path, &SystemRig, u64),
    method: Method,
    identification: Option<IdentifyParams>,
) -> Result<CalibrationSummary> {
    let s = device
        .upload_identifying(rig, fingerprint, method, identification)
        .with_context(|| format!("uploading {}", system.display()))?;
    link.output.status(format!(
        "uploaded {} ({} rays): fingerprint {:016x} read back, generation {}",
        system.display(),
        s.rays,
        s.fingerprint,
        s.generation
    ));
    Ok(s)
}

/// Check that `device` holds the calibration (`rig` with `fingerprint`) loaded from `system`;
/// upload it (with `identification`) when it does not and the device is in-process or in QEMU
/// (fresh each time) or `upload` says so, else fail saying how.
pub fn ensure_calibration(
    device: &mut AnyDevice,
    link: &LinkArgs,
    (system, rig, fingerprint): (&Path, &SystemRig, u64),
    method: Method,
    identification: Option<IdentifyParams>,
    upload: bool,
) -> Result<()> {
    match device.expect_system(rig, fingerprint) {
        Ok(_) => Ok(()),
        Err(DeviceError::Fingerprint { .. }) if upload || link.port.is_none() => {
            let system = (system, rig, fingerprint);
            upload_to(device, link, system, method, identification).map(|_| ())
        }
        Err(e @ DeviceError::Fingerprint { .. }) => Err(e).context(format!(
            "the device does not hold the calibration of {}: run `deltaz device upload` \
             (or `deltaz scan --upload`)",
            system.display()
        )),
        Err(e) => Err(e).context("asking the device for its calibration"),
    }
}

/// `deltaz device upload system.json`: status on stderr; with `--json` one object on stdout
/// (the calibration the device read back, the method and identification parameters).
pub fn upload(
    args: &LinkArgs,
    system: &Path,
    method: Method,
    identification: Option<IdentifyParams>,
) -> Result<()> {
    let (_, rig, fingerprint) = load_system(system)?;
    let mut device = connect(args)?;
    let s = upload_to(
        &mut device,
        args,
        (system, &rig, fingerprint),
        method,
        identification,
    )?;
    if args.port.is_none() {
        args.output.status(
            "note: the in-process and QEMU devices live only as long as this command; \
             `deltaz device stream --system` uploads to them itself",
        );
    }
    if args.output.json {
        let json = serde_json::json!({
            "system": system,
            "fingerprint": format!("{:016x}", s.fingerprint),
            "generation": s.generation,
            "rays": s.rays,
            "centroid_bits": s.centroid_bits,
            "method": method_name(method.into()),
            "identification": identification.map(|i| serde_json::json!({
                "near_mm": i.near,
                "far_mm": i.far,
                "tolerance_px": i.tolerance,
                "cell_px": i.cell,
            })),
            "persistent": args.port.is_some(),
        });
        println!("{json}");
    }
    Ok(())
}

/// The name of an intersection method as the CLI's `--method` spells it.
fn method_name(method: IntersectionMethod) -> &'static str {
    match method {
        IntersectionMethod::Paper => "paper",
        IntersectionMethod::ClosestApproach => "closest",
    }
}
