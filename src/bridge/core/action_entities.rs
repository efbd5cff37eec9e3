//! The Home Assistant entities of a profile's actions (command interfaces): a `button` for an
//! action without parameters, a `number` for one parameter, a `text` taking the JSON object of
//! its parameters for several. Each sends on the action's `…/<action>/set`, never retained; an
//! action has no state, so none has a state topic (Home Assistant shows what it sent). Pure:
//! the action in, the component JSON out.

use serde_json::{json, Map, Value as Json};

use super::entity_naming::display_name;
use rtu2mqtt_profile::contract::Topics;
use rtu2mqtt_profile::ActionInfo;

/// What the button of an action without parameters sends (any payload runs it).
const PAYLOAD_PRESS: &str = "PRESS";

/// The longest JSON object a `text` entity of an action lets one type.
const MAX_JSON_CHARS: usize = 255;

/// The component of `action` in its device's discovery document.
pub fn action_component(ctx: &Topics, device: &str, action: &ActionInfo) -> Json {
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
    use rtu2mqtt_profile::ActionParam;

    fn param(name: &str, min: i128, max: i128) -> ActionParam {
        ActionParam {
            name: name.to_string(),
            description: String::new(),
            unit: None,
            min,
            max,
        }
    }

    fn action(name: &str, params: Vec<ActionParam>) -> ActionInfo {
        ActionInfo {
            name: name.to_string(),
            description: String::new(),
            params,
            result: None,
        }
    }

    #[test]
    fn an_action_is_a_button_a_number_or_a_text_by_its_parameters() {
        let ctx = Topics::new("edge", "plant");
        assert_eq!(
            action_component(&ctx, "meter", &action("reset_energy", Vec::new())),
            json!({
                "p": "button",
                "name": "Reset energy",
                "unique_id": "edge_meter_reset_energy",
                "command_topic": "plant/meter/reset_energy/set",
                "retain": false,
                "payload_press": "PRESS",
            })
        );
        assert_eq!(
            action_component(
                &ctx,
                "meter",
                &action("set_tariff", vec![param("tariff", 1, 4)])
            ),
            json!({
                "p": "number",
                "name": "Set tariff",
                "unique_id": "edge_meter_set_tariff",
                "command_topic": "plant/meter/set_tariff/set",
                "retain": false,
                "min": 1,
                "max": 4,
                "step": 1,
                "mode": "box",
            })
        );
        let clock = action(
            "set_clock",
            vec![param("hour", 0, 23), param("minute", 0, 59)],
        );
        assert_eq!(
            action_component(&ctx, "meter", &clock),
            json!({
                "p": "text",
                "name": "Set clock",
                "unique_id": "edge_meter_set_clock",
                "command_topic": "plant/meter/set_clock/set",
                "retain": false,
                "max": 255,
            })
        );
    }
}
