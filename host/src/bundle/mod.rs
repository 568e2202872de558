//! Camera calibration by self-calibrating bundle adjustment (section 6.2.1, Table 1).

pub mod residual;
