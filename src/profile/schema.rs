//! The profile file format (serde) and its compilation into a validated [`super::Profile`].

/// The compiled, validated form of a profile.
#[derive(Debug, Clone)]
pub struct Compiled {}
