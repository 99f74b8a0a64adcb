//! firmware-sim: a simulated autopilot (work in progress).
