//! The logging shim: [`event!`](crate::logging::event) sends one device event (boot, upload,
//! bad frame, reset: never per point) to the `log` facade when the crate's `log` feature is on,
//! and compiles to nothing when it is off, its arguments not even evaluated: the default
//! firmware carries no formatting code for it (its ELFs are byte for byte those without the
//! calls). Whoever embeds the device with the feature installs a `log` logger (the host, a test);
//! the boards install none (their one UART carries the protocol), so there the records stop at
//! `log`'s level check.

/// Log one device event: `event!(info, "format", args…)` with a `log` level macro's name
/// (`error`, `warn`, `info`, `debug`, `trace`), target `deltaz::device`.
macro_rules! event {
    ($level:ident, $($arg:tt)+) => {{
        #[cfg(feature = "log")]
        ::log::$level!(target: "deltaz::device", $($arg)+);
    }};
}

pub(crate) use event;

#[cfg(all(test, feature = "log"))]
mod tests {
    use crate::device::NoProbe;
    use crate::ram_flash::RamFlash;
    use crate::server::Server;
    use crate::store::Store;
    use std::sync::Mutex;

    /// The records logged, as `level message`.
    static RECORDS: Mutex<Vec<String>> = Mutex::new(Vec::new());

    struct Capture;

    impl log::Log for Capture {
        fn enabled(&self, _: &log::Metadata) -> bool {
            true
        }
        fn log(&self, record: &log::Record) {
            if record.target() == "deltaz::device" {
                let line = format!("{} {}", record.level(), record.args());
                RECORDS.lock().unwrap().push(line);
            }
        }
        fn flush(&self) {}
    }

    /// With the feature, a boot without a calibration and a bad frame are logged.
    #[test]
    fn events_reach_the_log_facade() {
        log::set_logger(&Capture).unwrap();
        log::set_max_level(log::LevelFilter::Trace);
        let store = Store::new(
            RamFlash::<{ 8 * 4096 }>::new(),
            [(0, 16384), (16384, 32768)],
        )
        .unwrap();
        let mut server = Server::boot(store, NoProbe);
        for &byte in b"\x07garbage\x00" {
            server.push(byte, &mut |_| {});
        }
        let records = RECORDS.lock().unwrap().clone();
        assert!(
            records
                .iter()
                .any(|r| r == "INFO boot: no stored calibration"),
            "{records:?}"
        );
        assert!(
            records.iter().any(|r| r.starts_with("DEBUG bad frame")),
            "{records:?}"
        );
    }
}
