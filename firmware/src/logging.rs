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
