//! The templates Home Assistant renders on what the gateway publishes (Jinja in a discovery
//! document's `value_template`): a clock text as seconds, a command result as an event,
//! `unavailable` and a number's `also` values as unknown (`None`).

/// Turns a clock text `h:min:s` into seconds; anything else (the valve's `27:81:62` or
/// `00:00` mark an unset time) gives `None`, which Home Assistant shows as unknown.
pub const CLOCK_TO_SECONDS: &str = "{% set p = value.split(':') | map('int', -1) | list %}\
{% if p | length == 3 and p | min >= 0 and p[1] < 60 and p[2] < 60 %}\
{{ p[0] * 3600 + p[1] * 60 + p[2] }}{% else %}None{% endif %}";

/// Builds Home Assistant's event JSON (`event_type` plus attributes) from a `…/result`
/// payload: the outcome is the event type, the command and the detail its attributes.
pub const RESULT_EVENT_TEMPLATE: &str = "{{ {'event_type': value_json.outcome, \
'value': value_json.value, 'detail': value_json.detail} | to_json }}";

/// The `value_template` of a field that can be unavailable: that payload becomes `None`.
pub const UNAVAILABLE_AS_UNKNOWN: &str =
    "{% if value == 'unavailable' %}None{% else %}{{ value }}{% endif %}";

/// A number's `value_template` that turns the `also` values (and `unavailable`, when the field
/// can be) into `None` (unknown).
pub(crate) fn also_as_unknown(also: &[i64], may_be_unavailable: bool) -> String {
    let mut values: Vec<String> = also.iter().map(|value| format!("'{value}'")).collect();
    if may_be_unavailable {
        values.push(format!("'{}'", rtu2mqtt_profile::UNAVAILABLE));
    }
    format!(
        "{{% if value in [{}] %}}None{{% else %}}{{{{ value }}}}{{% endif %}}",
        values.join(", ")
    )
}
