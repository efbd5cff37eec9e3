//! A command as the plan of one bus slot, whatever it commands: fields written
//! read-modify-write and verified by reading them back (`command`'s `FieldPlan`), or an action's
//! frame written as it is and judged by its result register ([`ActionPlan`]). The line runs
//! both the same way, so an action takes the same queue, retained-command handling and
//! outcomes as any write. The profile's actions and their planning are here too.

use std::sync::Arc;
use std::time::Duration;

use super::action::ActionInfo;
use super::command::{FieldPlan, Verification};
use super::model::Compiled;
use super::rejection::Rejection;
use super::value::Value;
use super::Profile;
use rtu2mqtt_modbus::{Request, Response};

/// One planned command. The line runs: `reads_before()` → `writes(answers)` → the writes →
/// `readback()` → `verify(answers)`, with no other transaction in between.
///
/// A plan carries one field (`plan_command`), several fields written together in one frame
/// (`plan_group`, e.g. the dust collector's FC10 power-on with its settings), or an action
/// (`plan_action`: a command interface's frame and the read of its result register).
#[derive(Debug, Clone, PartialEq)]
pub struct CommandPlan(Plan);

#[derive(Debug, Clone, PartialEq)]
enum Plan {
    Fields(FieldPlan),
    Action(ActionPlan),
}

/// An action's slot: its one FC16 frame, then the read of its result register if it has one.
#[derive(Debug, Clone, PartialEq)]
struct ActionPlan {
    profile: Arc<Compiled>,
    /// Index into the profile's actions.
    action: usize,
    write: Request,
    /// The result register's read, or nothing.
    readback: Vec<Request>,
    /// The parameters as one value ([`CommandPlan::target`]).
    summary: Value,
}

impl ActionPlan {
    fn info(&self) -> &ActionInfo {
        &self.profile.actions[self.action].info
    }

    /// The result code judged: success codes are the device's word that it carried the
    /// command out; any other code (named when the profile names it) is not applied.
    fn verify(&self, answers: &[Response]) -> Verification {
        let info = self.info();
        let Some(result) = &info.result else {
            return Verification::Reported(
                "the device acknowledged the frame (the action has no result register to read)"
                    .to_string(),
            );
        };
        let code = answers.first().and_then(|answer| match answer {
            Response::HoldingRegisters(words) | Response::InputRegisters(words) => {
                words.first().copied()
            }
            _ => None,
        });
        match code {
            Some(code) if result.is_success(code) => Verification::Reported(format!(
                "the device reports result code {}",
                result.describe(code)
            )),
            Some(code) => Verification::NotApplied(format!(
                "{}: the device reports result code {}",
                info.name,
                result.describe(code)
            )),
            None => Verification::NotApplied(format!(
                "{}: the read of the result register answered no register",
                info.name
            )),
        }
    }
}

impl CommandPlan {
    /// The plan of a command on fields.
    pub(crate) fn from_fields(plan: FieldPlan) -> Self {
        Self(Plan::Fields(plan))
    }

    fn fields(&self) -> Option<&FieldPlan> {
        match &self.0 {
            Plan::Fields(plan) => Some(plan),
            Plan::Action(_) => None,
        }
    }

    /// The commanded field (for a group: the write frame's name; for an action: its name).
    pub fn field(&self) -> &str {
        match &self.0 {
            Plan::Fields(plan) => plan.field(),
            Plan::Action(plan) => &plan.info().name,
        }
    }

    /// The commanded value of the (first) field, parsed and normalised to its kind; for an
    /// action its parameters as one value (ON without parameters, the value of a single one,
    /// else their JSON object).
    pub fn target(&self) -> &Value {
        match &self.0 {
            Plan::Fields(plan) => plan.target(),
            Plan::Action(plan) => &plan.summary,
        }
    }

    /// Every commanded field with its value (none for an action: it writes no field).
    pub fn targets(&self) -> Vec<(&str, &Value)> {
        self.fields().map(FieldPlan::targets).unwrap_or_default()
    }

    /// Running the command twice leaves the device as running it once: every commanded field
    /// is a state (a momentary button, a toggle or an action is an act, not a state).
    pub fn is_idempotent(&self) -> bool {
        self.fields().is_some_and(FieldPlan::is_idempotent)
    }

    /// Reads to make in the slot before writing (empty when no read-modify-write is needed).
    pub fn reads_before(&self) -> &[Request] {
        self.fields().map_or(&[], FieldPlan::reads_before)
    }

    /// The write requests, computed from the fresh answers to `reads_before()`. Empty when the
    /// device already is in the commanded state (a toggle field asked for its current state).
    /// An action's one FC16 frame is fixed when it is planned.
    pub fn writes(&self, before: &[Response]) -> Result<Vec<Request>, Rejection> {
        match &self.0 {
            Plan::Fields(plan) => plan.writes(before),
            Plan::Action(plan) => Ok(vec![plan.write.clone()]),
        }
    }

    /// Reads that verify the command, made right after the writes; their answers go to
    /// [`CommandPlan::verify`]. An action's is the read of its result register.
    pub fn readback(&self) -> &[Request] {
        match &self.0 {
            Plan::Fields(plan) => plan.readback(),
            Plan::Action(plan) => &plan.readback,
        }
    }

    /// The profile's read blocks (indices into its `read_blocks()`) whose data the command can
    /// change, as the profile knows it: those its read-back looks at (the targets' block and
    /// the blocks of its settle conditions). None for an action.
    pub fn readback_blocks(&self) -> impl Iterator<Item = usize> + '_ {
        self.fields()
            .into_iter()
            .flat_map(FieldPlan::readback_blocks)
    }

    /// Judges the answers to `readback()`. The first call judges the read-back right after the
    /// write; later calls the repeated read-backs of a settling command.
    pub fn verify(&self, answers: &[Response]) -> Verification {
        match &self.0 {
            Plan::Fields(plan) => plan.verify(answers),
            Plan::Action(plan) => plan.verify(answers),
        }
    }

    /// How long a `Settling` read-back may keep being repeated (never for an action).
    pub fn settle_window(&self) -> Option<Duration> {
        self.fields().and_then(FieldPlan::settle_window)
    }
}

impl Profile {
    /// The profile's actions (`[[actions]]`), in file order.
    pub fn actions(&self) -> impl ExactSizeIterator<Item = &ActionInfo> + '_ {
        self.inner.actions.iter().map(|def| &def.info)
    }

    /// The action named `name`; `None` when the profile has no such action.
    pub fn action(&self, name: &str) -> Option<&ActionInfo> {
        self.actions().find(|info| info.name == name)
    }

    /// Validates a command on an action (`text` as received on `…/<action>/set`) against its
    /// parameters and plans its slot: the one FC16 frame, then the read of its result register.
    pub fn plan_action(&self, name: &str, text: &str) -> Result<CommandPlan, Rejection> {
        let inner = &self.inner;
        let index = inner
            .actions
            .iter()
            .position(|def| def.info.name == name)
            .ok_or_else(|| Rejection(format!("unknown action `{name}` for {}", inner.name)))?;
        let def = &inner.actions[index];
        let values = def.info.parse_payload(text)?;
        Ok(CommandPlan(Plan::Action(ActionPlan {
            profile: Arc::clone(inner),
            action: index,
            write: def.write(&values),
            readback: def.result_read.iter().cloned().collect(),
            summary: def.info.summary(&values),
        })))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const METER: &str = "[device]\nname = \"meter\"\nmanufacturer = \"m\"\nmodel = \"x\"\n[line]\n\
        [[blocks]]\nname = \"hold\"\nfunction = 3\nstart = 0\ncount = 1\n\
        [[fields]]\nname = \"tariff\"\nblock = \"hold\"\noffset = 0\ncodec = { type = \"u16\" }\n\
        range = [1, 4]\nwrite = { function = 6, address = 0 }\n\
        [[actions]]\nname = \"set_tariff\"\naddress = 5249\nregisters = [2060, 0, \"tariff\"]\n\
        params = { tariff = { range = [1, 4] } }\n\
        result = { address = 5375, codes = { 0 = \"ok\", 3001 = \"invalid parameter\" } }\n\
        [[actions]]\nname = \"reset_energy\"\naddress = 0x1000\nregisters = [1]\n";

    fn meter() -> Profile {
        Profile::from_toml(METER, "meter").expect("a valid profile")
    }

    #[test]
    fn an_action_is_one_frame_then_its_result_read() {
        let plan = meter()
            .plan_command("set_tariff", r#"{"tariff": 2}"#, &Default::default())
            .expect("a valid command");
        assert_eq!(plan.field(), "set_tariff");
        assert_eq!(plan.target(), &Value::Int(2));
        assert!(plan.targets().is_empty());
        assert!(!plan.is_idempotent());
        assert!(plan.reads_before().is_empty());
        assert_eq!(
            plan.writes(&[]),
            Ok(vec![Request::WriteMultipleRegisters {
                start: 5249,
                values: vec![2060, 0, 2],
            }])
        );
        assert_eq!(
            plan.readback(),
            [Request::ReadHoldingRegisters {
                start: 5375,
                quantity: 1
            }]
        );
        assert_eq!(plan.readback_blocks().count(), 0);
        assert_eq!(plan.settle_window(), None);
        assert_eq!(
            plan.verify(&[Response::HoldingRegisters(vec![0])]),
            Verification::Reported("the device reports result code 0 (ok)".into())
        );
        assert_eq!(
            plan.verify(&[Response::HoldingRegisters(vec![3001])]),
            Verification::NotApplied(
                "set_tariff: the device reports result code 3001 (invalid parameter)".into()
            )
        );
        assert_eq!(
            plan.verify(&[Response::HoldingRegisters(vec![9])]),
            Verification::NotApplied(
                "set_tariff: the device reports result code 9 (a code the profile does not name)"
                    .into()
            )
        );
    }

    #[test]
    fn an_action_without_result_is_done_when_its_frame_is_acknowledged() {
        let profile = meter();
        let plan = profile
            .plan_action("reset_energy", "PRESS")
            .expect("a valid command");
        assert_eq!(
            plan.writes(&[]),
            Ok(vec![Request::WriteMultipleRegisters {
                start: 0x1000,
                values: vec![1],
            }])
        );
        assert!(plan.readback().is_empty());
        assert_eq!(
            plan.verify(&[]),
            Verification::Reported(
                "the device acknowledged the frame (the action has no result register to read)"
                    .into()
            )
        );
        let listing = crate::registry::describe(&profile);
        assert!(
            listing.contains(
                "  action set_tariff     FC16 @0x1481 (5249)×3  tariff 1–4; result FC03 @0x14FF \
                 (5375): 0 ok, 3001 invalid parameter\n  action reset_energy   FC16 @0x1000 \
                 (4096)×1  no parameters; no result register\n"
            ),
            "{listing}"
        );
        let names: Vec<&str> = profile.actions().map(|a| a.name.as_str()).collect();
        assert_eq!(names, ["set_tariff", "reset_energy"]);
        assert!(profile
            .action("reset_energy")
            .is_some_and(|a| a.params.is_empty()));
    }

    #[test]
    fn a_refused_parameter_plans_nothing() {
        let profile = meter();
        assert_eq!(
            profile.plan_action("set_tariff", r#"{"tariff": 9}"#),
            Err(Rejection(
                "set_tariff: tariff must be an integer 1–4, got 9".into()
            ))
        );
        assert_eq!(
            profile.plan_action("set_rate", "1"),
            Err(Rejection("unknown action `set_rate` for meter".into()))
        );
        // A field of the same profile is still a field.
        let field = profile
            .plan_command("tariff", "3", &Default::default())
            .expect("a field command");
        assert_eq!(field.targets().len(), 1);
    }
}
