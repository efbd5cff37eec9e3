//! The Home Assistant entities of a profile's actions (command interfaces): a `button` for an
//! action without parameters, a `number` for one parameter, a `text` taking the JSON object of
//! its parameters for several. Each sends on the action's `…/<action>/set`, never retained; an
//! action has no state, so none has a state topic (Home Assistant shows what it sent). Pure:
//! the action in, the component JSON out.

use serde_json::{json, Map, Value as Json};

use super::entity_naming::display_name;
use crate::topics::Topics;
use rtu2mqtt_profile::ActionInfo;

/// What the button of an action without parameters sends (any payload runs it).
const PAYLOAD_PRESS: &str = "PRESS";

/// The longest JSON object a `text` entity of an action lets one type.
const MAX_JSON_CHARS: usize = 255;

/// Adds the component of each of `actions` to a device's discovery `components`, keyed by
/// the action's name; whether there was any.
pub fn add_action_components<'a>(
    ctx: &Topics,
    device: &str,
    actions: impl Iterator<Item = &'a ActionInfo>,
    components: &mut Map<String, Json>,
) -> bool {
    let before = components.len();
    for action in actions {
        components.insert(action.name.clone(), action_component(ctx, device, action));
    }
    components.len() > before
}

/// The component of `action` in its device's discovery document.
fn action_component(ctx: &Topics, device: &str, action: &ActionInfo) -> Json {
    let mut config = Map::new();
    let mut put = |key: &str, value: Json| {
        config.insert(key.to_string(), value);
    };
    put("name", json!(display_name(&action.name)));
    put("unique_id", json!(ctx.unique_id(device, &action.name)));
    put(
        "command_topic",
        json!(ctx.command_topic(device, &action.name)),
    );
    // Never leave a command retained in the broker on Home Assistant's behalf.
    put("retain", json!(false));
    match action.params.as_slice() {
        [] => {
            put("p", json!("button"));
            put("payload_press", json!(PAYLOAD_PRESS));
        }
        [param] => {
            put("p", json!("number"));
            put("min", json!(param.min));
            put("max", json!(param.max));
            put("step", json!(1));
            put("mode", json!("box"));
            if let Some(unit) = &param.unit {
                put("unit_of_measurement", json!(unit));
            }
        }
        _ => {
            put("p", json!("text"));
            put("max", json!(MAX_JSON_CHARS));
        }
    }
    Json::Object(config)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_profile::Profile;

    const METER: &str = "[device]\nname = \"meter\"\nmanufacturer = \"m\"\nmodel = \"x\"\n[line]\n\
        [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 0\ncount = 1\n\
        [[fields]]\nname = \"energy\"\nblock = \"hold\"\noffset = 0\ncodec = { type = \"u16\" }\n\
        [[actions]]\nname = \"reset_energy\"\naddress = 9\nregisters = [1]\n\
        [[actions]]\nname = \"set_tariff\"\naddress = 9\nregisters = [2, \"tariff\"]\n\
        params = { tariff = { range = [1, 4] } }\n\
        [[actions]]\nname = \"set_clock\"\naddress = 9\nregisters = [3, \"hour\", \"minute\"]\n";

    #[test]
    fn an_action_is_a_button_a_number_or_a_text_by_its_parameters() {
        let profile = match Profile::from_toml(METER, "meter") {
            Ok(profile) => profile,
            Err(errors) => panic!("{errors}"),
        };
        let ctx = Topics::new("edge", "plant");
        let component = |name: &str| {
            profile
                .action(name)
                .map(|action| action_component(&ctx, "meter", action))
        };
        assert_eq!(
            component("reset_energy"),
            Some(json!({
                "p": "button",
                "name": "Reset energy",
                "unique_id": "edge_meter_reset_energy",
                "command_topic": "plant/meter/reset_energy/set",
                "retain": false,
                "payload_press": "PRESS",
            }))
        );
        assert_eq!(
            component("set_tariff"),
            Some(json!({
                "p": "number",
                "name": "Set tariff",
                "unique_id": "edge_meter_set_tariff",
                "command_topic": "plant/meter/set_tariff/set",
                "retain": false,
                "min": 1,
                "max": 4,
                "step": 1,
                "mode": "box",
            }))
        );
        assert_eq!(
            component("set_clock"),
            Some(json!({
                "p": "text",
                "name": "Set clock",
                "unique_id": "edge_meter_set_clock",
                "command_topic": "plant/meter/set_clock/set",
                "retain": false,
                "max": 255,
            }))
        );
    }
}
