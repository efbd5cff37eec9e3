//! (bus helper)
