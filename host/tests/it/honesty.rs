//! The one bar every σ in these tests is held to.
use std::fmt::Display;

/// Asserts that an RMS of error/σ lies in 0.8-1.25: the propagated σ neither understates nor
/// overstates the errors it claims to bound. `what` names the figure in the failure.
pub fn assert_honest(rms: f64, what: impl Display) {
    assert!(
        (0.8..=1.25).contains(&rms),
        "{what}: RMS of error/σ {rms:.2}"
    );
}
