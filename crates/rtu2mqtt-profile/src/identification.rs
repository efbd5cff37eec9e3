//! A profile's `[device] identification`: what the device it describes says of itself when
//! asked, so that a scan can name the profile. Either the device's Read Device Identification
//! (FC43/14: its VendorName and ProductCode, the product code as one pattern or a list) or its
//! SunSpec map (the "SunS" marker at a base, then the first models of the chain), or both:
//!
//! ```toml
//! [device]
//! identification = { vendor = "Schneider Electric", product_code = ["A9MEM3155", "A9MEM3165"] }
//! # or
//! identification = { sunspec_base = 40000, sunspec_models = [1, 103] }
//! ```
//!
//! A product code pattern is matched whole, ignoring case, `*` standing for any run of
//! characters (`A9MEM31*5`); the vendor is matched whole, ignoring case and runs of spaces.

use serde::Deserialize;

/// The key as written in the profile file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct IdentificationSection {
    vendor: Option<String>,
    product_code: Option<OneOrMany>,
    sunspec_base: Option<u16>,
    sunspec_models: Option<Vec<u16>>,
}

/// One product code pattern, or a list of them.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum OneOrMany {
    One(String),
    Many(Vec<String>),
}

/// What a device reports when it is the device a profile describes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identification {
    /// The VendorName (object 0x00) and the ProductCode patterns (object 0x01).
    read_device_id: Option<(String, Vec<String>)>,
    /// The SunSpec base and the models the chain starts with there.
    sunspec: Option<(u16, Vec<u16>)>,
}

/// Longest vendor name or product code pattern a profile may give (longer ones could never be
/// in one answer).
const MAX_TEXT: usize = 244;

impl Identification {
    /// The key's meaning, or why it has none (the sentence for the profile's problem).
    pub(crate) fn from_section(section: IdentificationSection) -> Result<Self, String> {
        let read_device_id = match (section.vendor, section.product_code) {
            (None, None) => None,
            (Some(vendor), Some(codes)) => {
                let codes = match codes {
                    OneOrMany::One(code) => vec![code],
                    OneOrMany::Many(codes) => codes,
                };
                let vendor = vendor.trim().to_string();
                if vendor.is_empty() || codes.is_empty() {
                    return Err("`vendor` and `product_code` must not be empty".into());
                }
                for text in codes.iter().chain([&vendor]) {
                    if text.trim().is_empty() || text.len() > MAX_TEXT || !text.is_ascii() {
                        return Err(format!(
                            "`{text}`: a vendor or product code is 1–{MAX_TEXT} ASCII characters"
                        ));
                    }
                }
                Some((vendor, codes))
            }
            _ => return Err("`vendor` and `product_code` go together".into()),
        };
        let sunspec = match (section.sunspec_base, section.sunspec_models) {
            (None, None) => None,
            (Some(_), Some(models)) if models.is_empty() => {
                return Err("`sunspec_models` names at least the first model".into())
            }
            (Some(base), Some(models)) => Some((base, models)),
            _ => return Err("`sunspec_base` and `sunspec_models` go together".into()),
        };
        if read_device_id.is_none() && sunspec.is_none() {
            return Err(
                "give `vendor` and `product_code`, or `sunspec_base` and `sunspec_models`".into(),
            );
        }
        Ok(Self {
            read_device_id,
            sunspec,
        })
    }

    /// The VendorName the device reports, if the profile names one.
    pub fn vendor(&self) -> Option<&str> {
        self.read_device_id
            .as_ref()
            .map(|(vendor, _)| vendor.as_str())
    }

    /// The ProductCode patterns.
    pub fn product_codes(&self) -> &[String] {
        self.read_device_id
            .as_ref()
            .map_or(&[], |(_, codes)| codes.as_slice())
    }

    /// The SunSpec base and the first models of the chain there, if the profile names them.
    pub fn sunspec(&self) -> Option<(u16, &[u16])> {
        self.sunspec
            .as_ref()
            .map(|(base, models)| (*base, models.as_slice()))
    }

    /// True when a device reporting `vendor` and `product_code` is this profile's.
    pub fn matches_device_id(&self, vendor: &str, product_code: &str) -> bool {
        let Some((expected, patterns)) = &self.read_device_id else {
            return false;
        };
        same_words(expected, vendor)
            && patterns
                .iter()
                .any(|pattern| glob_matches(pattern.trim(), product_code.trim()))
    }

    /// True when a SunSpec map at `base` whose chain starts with `models` is this profile's.
    pub fn matches_sunspec(&self, base: u16, models: &[u16]) -> bool {
        self.sunspec
            .as_ref()
            .is_some_and(|(expected, first)| *expected == base && models.starts_with(first))
    }
}

impl std::fmt::Display for Identification {
    /// `vendor "Schneider Electric", product code A9MEM3155 or A9MEM3165` and/or
    /// `SunSpec map at 40000 starting with models 1, 103`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut parts = Vec::new();
        if let Some((vendor, codes)) = &self.read_device_id {
            parts.push(format!(
                "vendor \"{vendor}\", product code {}",
                codes.join(" or ")
            ));
        }
        if let Some((base, models)) = &self.sunspec {
            let models: Vec<String> = models.iter().map(u16::to_string).collect();
            parts.push(format!(
                "SunSpec map at {base} starting with model{} {}",
                if models.len() == 1 { "" } else { "s" },
                models.join(", ")
            ));
        }
        f.write_str(&parts.join("; "))
    }
}

/// Equal ignoring ASCII case and runs of white space (padding included).
fn same_words(a: &str, b: &str) -> bool {
    let words = |text: &str| {
        text.split_whitespace()
            .map(str::to_ascii_lowercase)
            .collect::<Vec<_>>()
    };
    words(a) == words(b)
}

/// `text` matched whole by `pattern`, ignoring ASCII case, `*` matching any run of characters.
fn glob_matches(pattern: &str, text: &str) -> bool {
    let pattern = pattern.to_ascii_lowercase();
    let text = text.to_ascii_lowercase();
    let mut parts = pattern.split('*');
    let first = parts.next().unwrap_or_default();
    let Some(mut rest) = text.strip_prefix(first) else {
        return false;
    };
    let middle: Vec<&str> = parts.collect();
    let Some((last, between)) = middle.split_last() else {
        // No `*`: the whole text is the pattern.
        return rest.is_empty();
    };
    for part in between {
        match rest.find(part) {
            Some(at) => rest = &rest[at + part.len()..],
            None => return false,
        }
    }
    rest.ends_with(last)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Identification, String> {
        let section: IdentificationSection = toml::from_str(text).map_err(|e| e.to_string())?;
        Identification::from_section(section)
    }

    #[test]
    fn product_codes_match_whole_with_stars_and_any_case() {
        assert!(glob_matches("A9MEM3155", "a9mem3155"));
        assert!(!glob_matches("A9MEM3155", "A9MEM31550"));
        assert!(glob_matches("A9MEM31*5", "A9MEM3155"));
        assert!(glob_matches("A9MEM31*5", "A9MEM3165"));
        assert!(!glob_matches("A9MEM31*5", "A9MEM3156"));
        assert!(glob_matches("*3155", "A9MEM3155"));
        assert!(glob_matches("A*M*5", "A9MEM3155"));
        assert!(!glob_matches("A*X*5", "A9MEM3155"));
        assert!(glob_matches("*", "anything"));
        // The pattern's ends do not overlap: `ab*ba` needs at least `ab` and `ba`.
        assert!(!glob_matches("ab*ba", "aba"));
    }

    #[test]
    fn a_device_id_matches_its_vendor_and_one_of_its_codes() {
        let id =
            parse("vendor = \"Schneider Electric\"\nproduct_code = [\"A9MEM3155\", \"A9MEM3165\"]")
                .unwrap();
        assert!(id.matches_device_id("Schneider Electric", "A9MEM3165"));
        assert!(id.matches_device_id("  SCHNEIDER   electric ", "A9MEM3155 "));
        assert!(!id.matches_device_id("Schneider", "A9MEM3155"));
        assert!(!id.matches_device_id("Schneider Electric", "A9MEM3175"));
        assert!(!id.matches_sunspec(40000, &[1, 103]));
        assert_eq!(id.vendor(), Some("Schneider Electric"));
        assert_eq!(
            id.to_string(),
            "vendor \"Schneider Electric\", product code A9MEM3155 or A9MEM3165"
        );
        let one = parse("vendor = \"ACME\"\nproduct_code = \"X-1\"").unwrap();
        assert_eq!(one.product_codes(), ["X-1"]);
    }

    #[test]
    fn a_sunspec_map_matches_its_base_and_first_models() {
        let id = parse("sunspec_base = 40000\nsunspec_models = [1, 103]").unwrap();
        assert!(id.matches_sunspec(40000, &[1, 103]));
        assert!(id.matches_sunspec(40000, &[1, 103, 160]));
        assert!(!id.matches_sunspec(40000, &[1, 101]));
        assert!(!id.matches_sunspec(0, &[1, 103]));
        assert!(!id.matches_device_id("SunSpec", "x"));
        assert_eq!(
            id.to_string(),
            "SunSpec map at 40000 starting with models 1, 103"
        );
    }

    #[test]
    fn half_given_or_empty_keys_are_refused() {
        for text in [
            "vendor = \"ACME\"",
            "product_code = \"X\"",
            "vendor = \"\"\nproduct_code = \"X\"",
            "vendor = \"ACME\"\nproduct_code = []",
            "vendor = \"ACME\"\nproduct_code = [\" \"]",
            "sunspec_base = 40000",
            "sunspec_base = 40000\nsunspec_models = []",
            "",
        ] {
            assert!(parse(text).is_err(), "{text:?} accepted");
        }
        assert!(parse("model = \"x\"").is_err());
    }
}
