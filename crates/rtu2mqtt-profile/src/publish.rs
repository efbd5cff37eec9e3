//! When a field's value is worth publishing: the `publish` settings (a field's own table in a
//! profile, or a device's default in the configuration), their checks, and the exact rule that
//! says whether a value moved far enough from the last published one. Pure: no clock here; the
//! timing (`min_interval`, `max_interval`) is applied by the line's reporter.

use std::time::Duration;

use serde::Deserialize;

use super::number::DecimalText;
use super::value::Value;

/// The shortest heartbeat: a value republished more often than this floods the broker.
const MIN_MAX_INTERVAL: Duration = Duration::from_secs(1);
/// Most decimals a deadband may have.
const MAX_DECIMALS: u8 = 9;

/// The `publish` table as written (`publish = { deadband = 0.5, max_interval = "60s" }`).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPublish {
    /// Publish a number when it moved more than this from the last published value.
    pub deadband: Option<f64>,
    /// Publish a number when it moved more than this percentage of the last published value.
    pub deadband_percent: Option<f64>,
    /// At most one publication per interval (the newest value goes out when it ends).
    #[serde(default, with = "humantime_serde")]
    pub min_interval: Option<Duration>,
    /// Publish again, unchanged, after this long without a publication (a heartbeat).
    #[serde(default, with = "humantime_serde")]
    pub max_interval: Option<Duration>,
}

/// A non-negative decimal amount, kept exact: `scaled / 10^decimals`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Amount {
    scaled: i64,
    decimals: u8,
}

impl Amount {
    /// `text` (plain decimal notation) as an amount; None when negative, not a number, with
    /// more than nine decimals or too large for 64 bits once scaled.
    pub fn parse(text: &str) -> Option<Amount> {
        let number = DecimalText::parse(text)?;
        let decimals = (0..=MAX_DECIMALS).find(|&d| number.scaled(d).is_ok())?;
        let scaled = i64::try_from(number.scaled(decimals).ok()?).ok()?;
        (scaled >= 0).then_some(Amount { scaled, decimals })
    }

    /// A number as TOML gave it: through its shortest decimal text, which is the text written
    /// for any number of up to 15 significant digits, so `0.1` is exactly one tenth.
    fn from_float(number: f64) -> Option<Amount> {
        if !number.is_finite() || number < 0.0 {
            return None;
        }
        Amount::parse(&format!("{number}"))
    }
}

impl std::fmt::Display for Amount {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let value = Value::Decimal {
            scaled: i128::from(self.scaled),
            precision: self.decimals,
        };
        f.write_str(&value.to_text())
    }
}

/// Checked `publish` settings; every key optional ([`PublishRule::default`] publishes every
/// change at once, as without settings).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PublishRule {
    /// `deadband`: a number is published when it moved more than this, in the field's own
    /// unit, from the last published value.
    pub deadband: Option<Amount>,
    /// `deadband_percent`: a number is published when it moved more than this percentage of
    /// the last published value.
    pub deadband_percent: Option<Amount>,
    /// `min_interval`: at most one publication per interval; the newest value goes out when
    /// it ends.
    pub min_interval: Option<Duration>,
    /// `max_interval`: the value is published again, unchanged, after this long without a
    /// publication (a heartbeat, at least one second).
    pub max_interval: Option<Duration>,
}

/// A problem of a `publish` table: the key it is about and why.
pub type PublishProblem = (&'static str, String);

impl PublishRule {
    /// Checks `raw`; every problem with its key.
    pub fn from_raw(raw: &RawPublish) -> Result<PublishRule, Vec<PublishProblem>> {
        let mut problems = Vec::new();
        let mut amount = |key: &'static str, number: Option<f64>| {
            let number = number?;
            let amount = Amount::from_float(number);
            if amount.is_none() {
                problems.push((
                    key,
                    format!(
                        "{number} is not a number of at least 0 with at most {MAX_DECIMALS} \
                         decimals"
                    ),
                ));
            }
            amount
        };
        let rule = PublishRule {
            deadband: amount("deadband", raw.deadband),
            deadband_percent: amount("deadband_percent", raw.deadband_percent),
            min_interval: raw.min_interval,
            max_interval: raw.max_interval,
        };
        if let Some(max) = rule.max_interval {
            if max < MIN_MAX_INTERVAL {
                problems.push((
                    "max_interval",
                    format!(
                        "{} is under the shortest heartbeat, {}",
                        humantime::format_duration(max),
                        humantime::format_duration(MIN_MAX_INTERVAL)
                    ),
                ));
            }
        }
        problems.extend(
            rule.interval_problem()
                .map(|reason| ("min_interval", reason)),
        );
        if problems.is_empty() {
            Ok(rule)
        } else {
            Err(problems)
        }
    }

    /// No key is set: every change is published at once.
    pub fn is_empty(&self) -> bool {
        *self == PublishRule::default()
    }

    /// A deadband is set (it only applies to numbers).
    fn has_deadband(&self) -> bool {
        self.deadband.is_some() || self.deadband_percent.is_some()
    }

    /// These settings, with each key they lack taken from `default`.
    pub fn or(self, default: PublishRule) -> PublishRule {
        PublishRule {
            deadband: self.deadband.or(default.deadband),
            deadband_percent: self.deadband_percent.or(default.deadband_percent),
            min_interval: self.min_interval.or(default.min_interval),
            max_interval: self.max_interval.or(default.max_interval),
        }
    }

    /// `min_interval` over `max_interval`: the heartbeat would come before a change may.
    pub fn interval_problem(&self) -> Option<String> {
        match (self.min_interval, self.max_interval) {
            (Some(min), Some(max)) if min > max => Some(format!(
                "min_interval {} is over max_interval {}",
                humantime::format_duration(min),
                humantime::format_duration(max)
            )),
            _ => None,
        }
    }

    /// Whether `new` differs enough from `last`, the last published value, to be published:
    /// a number moved more than `deadband`, or more than `deadband_percent` of `last` (from
    /// zero, any move is more); anything else, or a number without a deadband, changed at all.
    /// Exact: fixed-point arithmetic on the values' own digits.
    pub fn moved(&self, last: &Value, new: &Value) -> bool {
        if !self.has_deadband() {
            return last != new;
        }
        let (Some(last), Some(new)) = (fixed(last), fixed(new)) else {
            return last != new;
        };
        self.number_moved(last, new).unwrap_or(true)
    }

    /// [`PublishRule::moved`] for two numbers; None when the arithmetic would overflow (then
    /// the value is published: a move that large is no small change).
    fn number_moved(&self, (last, last_dp): (i128, u8), (new, new_dp): (i128, u8)) -> Option<bool> {
        let band_dp = self.deadband.map_or(0, |band| band.decimals);
        let common = last_dp.max(new_dp).max(band_dp);
        let last = rescale(last, last_dp, common)?;
        let new = rescale(new, new_dp, common)?;
        let change = new.checked_sub(last)?.checked_abs()?;
        let mut moved = false;
        if let Some(band) = self.deadband {
            moved |= change > rescale(i128::from(band.scaled), band.decimals, common)?;
        }
        if let Some(percent) = self.deadband_percent {
            // change > |last| × percent / 100, with percent = scaled / 10^decimals.
            let left = change
                .checked_mul(100)?
                .checked_mul(10i128.checked_pow(u32::from(percent.decimals))?)?;
            let right = last
                .checked_abs()?
                .checked_mul(i128::from(percent.scaled))?;
            moved |= left > right;
        }
        Some(moved)
    }
}

/// A number as (scaled, decimals); None for anything else.
fn fixed(value: &Value) -> Option<(i128, u8)> {
    match value {
        Value::Int(number) => Some((*number, 0)),
        Value::Decimal { scaled, precision } => Some((*scaled, *precision)),
        _ => None,
    }
}

fn rescale(scaled: i128, from: u8, to: u8) -> Option<i128> {
    scaled.checked_mul(10i128.checked_pow(u32::from(to.checked_sub(from)?))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decimal(scaled: i64, precision: u8) -> Value {
        Value::Decimal {
            scaled: scaled.into(),
            precision,
        }
    }

    fn rule(deadband: Option<f64>, percent: Option<f64>) -> PublishRule {
        PublishRule::from_raw(&RawPublish {
            deadband,
            deadband_percent: percent,
            ..RawPublish::default()
        })
        .unwrap()
    }

    #[test]
    fn amounts_are_the_decimals_written() {
        assert_eq!(Amount::from_float(0.1).unwrap().to_string(), "0.1");
        assert_eq!(Amount::from_float(0.3).unwrap().to_string(), "0.3");
        assert_eq!(Amount::from_float(2.0).unwrap().to_string(), "2");
        assert_eq!(
            Amount::from_float(0.000001).unwrap().to_string(),
            "0.000001"
        );
        assert_eq!(Amount::from_float(-0.5), None);
        assert_eq!(Amount::from_float(f64::NAN), None);
        assert_eq!(Amount::from_float(1e-12), None, "too many decimals");
        assert_eq!(Amount::parse("1e3"), None);
    }

    #[test]
    fn an_absolute_deadband_is_exceeded_only_beyond_its_edge() {
        let band = rule(Some(0.5), None);
        let last = decimal(2000, 2); // 20.00
        assert!(!band.moved(&last, &decimal(2050, 2)), "exactly 0.5 up");
        assert!(!band.moved(&last, &decimal(1950, 2)), "exactly 0.5 down");
        assert!(band.moved(&last, &decimal(2051, 2)));
        assert!(band.moved(&last, &decimal(1949, 2)));
        // 0.1 + 0.2 is 0.3 here: a band of 0.3 is not exceeded by a move of exactly 0.3.
        let tenths = rule(Some(0.3), None);
        assert!(!tenths.moved(&decimal(1, 1), &decimal(4, 1)));
        assert!(tenths.moved(&decimal(10, 2), &decimal(41, 2)));
        // Integers, and a value whose precision changed.
        let counts = rule(Some(2.0), None);
        assert!(!counts.moved(&Value::Int(10), &Value::Int(12)));
        assert!(counts.moved(&Value::Int(10), &Value::Int(13)));
        assert!(!counts.moved(&Value::Int(10), &decimal(1200, 2)));
        assert!(counts.moved(&Value::Int(10), &decimal(1201, 2)));
    }

    #[test]
    fn negative_numbers_move_by_their_distance() {
        let band = rule(Some(1.0), None);
        let last = decimal(-50, 1); // -5.0
        assert!(!band.moved(&last, &decimal(-60, 1)));
        assert!(!band.moved(&last, &decimal(-40, 1)));
        assert!(band.moved(&last, &decimal(-61, 1)));
        assert!(band.moved(&last, &decimal(-39, 1)));
        // Across zero.
        assert!(!band.moved(&decimal(-5, 1), &decimal(5, 1)));
        assert!(band.moved(&decimal(-5, 1), &decimal(6, 1)));
        // A percentage of a negative value is of its size.
        let percent = rule(None, Some(10.0));
        assert!(!percent.moved(&Value::Int(-200), &Value::Int(-220)));
        assert!(percent.moved(&Value::Int(-200), &Value::Int(-221)));
        assert!(!percent.moved(&Value::Int(-200), &Value::Int(-180)));
        assert!(percent.moved(&Value::Int(-200), &Value::Int(-179)));
    }

    #[test]
    fn a_percent_deadband_is_of_the_last_published_value() {
        let band = rule(None, Some(1.0));
        let last = decimal(12345, 1); // 1234.5: 1 % is 12.345
        assert!(!band.moved(&last, &decimal(12468, 1)), "12.3 up");
        assert!(band.moved(&last, &decimal(12469, 1)), "12.4 up");
        // Exactly at the edge: 1 % of 200 is 2.
        assert!(!band.moved(&Value::Int(200), &Value::Int(202)));
        assert!(band.moved(&Value::Int(200), &Value::Int(203)));
        let fine = rule(None, Some(0.25));
        assert!(
            !fine.moved(&decimal(4000, 2), &decimal(4010, 2)),
            "0.25 % of 40"
        );
        assert!(fine.moved(&decimal(4000, 2), &decimal(4011, 2)));
    }

    #[test]
    fn from_zero_any_move_exceeds_a_percentage() {
        let band = rule(None, Some(5.0));
        assert!(!band.moved(&Value::Int(0), &Value::Int(0)));
        assert!(band.moved(&Value::Int(0), &Value::Int(1)));
        assert!(band.moved(&decimal(0, 2), &decimal(-1, 2)));
        // Either band suffices.
        let both = rule(Some(1.0), Some(50.0));
        assert!(!both.moved(&Value::Int(0), &Value::Int(0)));
        assert!(
            both.moved(&Value::Int(0), &Value::Int(1)),
            "the percentage, from zero"
        );
        assert!(!both.moved(&Value::Int(10), &Value::Int(11)), "neither");
        assert!(
            both.moved(&Value::Int(10), &Value::Int(12)),
            "the absolute one"
        );
    }

    #[test]
    fn anything_but_a_number_moves_on_any_change() {
        let band = rule(Some(5.0), Some(5.0));
        assert!(!band.moved(&Value::Bool(true), &Value::Bool(true)));
        assert!(band.moved(&Value::Bool(true), &Value::Bool(false)));
        assert!(band.moved(&Value::Enum("opening".into()), &Value::Enum("open".into())));
        assert!(!band.moved(&Value::Text("A1".into()), &Value::Text("A1".into())));
        let none = PublishRule::default();
        assert!(none.moved(&Value::Int(1), &Value::Int(2)));
        assert!(!none.moved(&Value::Int(2), &Value::Int(2)));
    }

    #[test]
    fn huge_moves_are_moves() {
        let band = rule(Some(0.000000001), Some(0.000000001));
        assert!(band.moved(&decimal(i64::MIN, 18), &decimal(i64::MAX, 0)));
    }

    #[test]
    fn bad_settings_are_refused_with_their_key() {
        let problems = |raw: RawPublish| PublishRule::from_raw(&raw).unwrap_err();
        let keys =
            |found: Vec<PublishProblem>| found.into_iter().map(|(k, _)| k).collect::<Vec<_>>();
        assert_eq!(
            keys(problems(RawPublish {
                deadband: Some(-0.5),
                deadband_percent: Some(-1.0),
                ..RawPublish::default()
            })),
            ["deadband", "deadband_percent"]
        );
        let found = problems(RawPublish {
            min_interval: Some(Duration::from_secs(90)),
            max_interval: Some(Duration::from_secs(60)),
            ..RawPublish::default()
        });
        assert_eq!(
            found,
            [(
                "min_interval",
                "min_interval 1m 30s is over max_interval 1m".to_string()
            )]
        );
        assert_eq!(
            keys(problems(RawPublish {
                max_interval: Some(Duration::from_millis(10)),
                ..RawPublish::default()
            })),
            ["max_interval"]
        );
    }

    #[test]
    fn a_fields_own_keys_win_key_by_key() {
        let own = PublishRule {
            deadband: Amount::parse("0.5"),
            ..PublishRule::default()
        };
        let device = PublishRule {
            deadband: Amount::parse("2"),
            deadband_percent: Amount::parse("1"),
            max_interval: Some(Duration::from_secs(60)),
            ..PublishRule::default()
        };
        let merged = own.or(device);
        assert_eq!(merged.deadband, Amount::parse("0.5"));
        assert_eq!(merged.deadband_percent, Amount::parse("1"));
        assert_eq!(merged.max_interval, Some(Duration::from_secs(60)));
        assert_eq!(merged.min_interval, None);
        assert!(PublishRule::default().is_empty() && !merged.is_empty());
    }
}
