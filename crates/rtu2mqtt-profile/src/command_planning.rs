//! Planning commands on a profile's fields: a field's own command, several fields through a
//! shared write frame, and a foreign master's write as the fields it sets. Each is validated
//! against the field rules and the last known state before it becomes a [`CommandPlan`].

use std::sync::Arc;

use rtu2mqtt_modbus::Request;

use crate::command::FieldPlan;
use crate::{model, CommandPlan, DeviceState, Profile, Rejection, Value};

impl Profile {
    /// Plans a foreign master's `write` as the fields it sets (`values`, command texts) written
    /// through the very frame the write lands on, so that the device gets the frame a client
    /// sent and not another one that would also rewrite other fields. Validated like a command
    /// on the last known `state`; labelled by the frame's name when it is a shared one.
    pub fn plan_foreign_write(
        &self,
        write: &Request,
        values: &[(&str, &str)],
        state: &DeviceState,
    ) -> Result<CommandPlan, Rejection> {
        let Some((frame, _)) = self.landing(write) else {
            return Err(Rejection("the write lands on no write frame".to_string()));
        };
        let named = self
            .inner
            .named_frames
            .iter()
            .find(|(_, named)| named == frame)
            .map(|(name, _)| name.as_str());
        let label = match (values, named) {
            ([(field, _)], _) => field,
            (_, Some(name)) => name,
            ([(field, _), ..], None) => field,
            ([], _) => return Err(Rejection("the write sets no field".to_string())),
        };
        self.plan_frame(label, frame.clone(), values, state)
    }

    /// Validates a command (`text` as received on `…/set`) against the field's rules and the
    /// last known state, and plans the bus slot that carries it out. A name that is one of the
    /// profile's actions plans that action ([`Profile::plan_action`]).
    pub fn plan_command(
        &self,
        field: &str,
        text: &str,
        state: &DeviceState,
    ) -> Result<CommandPlan, Rejection> {
        if self.field(field).is_none() && self.action(field).is_some() {
            return self.plan_action(field, text);
        }
        let (index, target) = self.parse_target(field, text)?;
        let Some(frame) = self.inner.defs[index].write.clone() else {
            return Err(Rejection(format!("{field} is read-only")));
        };
        let targets = vec![(index, target)];
        self.check_known_state(&targets, state)?;
        Ok(CommandPlan::from_fields(FieldPlan::new(
            Arc::clone(&self.inner),
            field.to_string(),
            frame,
            targets,
        )))
    }

    /// Plans several fields written together through one named `[[write_frames]]` entry in one
    /// frame (the dust collector's `settings`: power on with gear and timers in one FC10). Bits
    /// and words of the frame that no value names are written back as freshly read.
    pub fn plan_group(
        &self,
        frame_name: &str,
        values: &[(&str, &str)],
        state: &DeviceState,
    ) -> Result<CommandPlan, Rejection> {
        let inner = &self.inner;
        let frame = inner
            .named_frames
            .iter()
            .find(|(name, _)| name == frame_name)
            .map(|(_, frame)| frame.clone())
            .ok_or_else(|| {
                Rejection(format!(
                    "unknown write frame `{frame_name}` for {}",
                    inner.name
                ))
            })?;
        self.plan_frame(frame_name, frame, values, state)
    }

    /// Plans `values` written together through `frame`, labelled `label`.
    fn plan_frame(
        &self,
        frame_name: &str,
        frame: model::WriteFrame,
        values: &[(&str, &str)],
        state: &DeviceState,
    ) -> Result<CommandPlan, Rejection> {
        let inner = &self.inner;
        if values.is_empty() {
            return Err(Rejection(format!("{frame_name}: no values given")));
        }
        let mut targets: Vec<(usize, Value)> = Vec::new();
        for (field, text) in values {
            let (index, target) = self.parse_target(field, text)?;
            let def = &inner.defs[index];
            let end = u32::from(def.offset) + u32::from(def.codec.width());
            if def.block != frame.block
                || def.offset < frame.offset
                || end > u32::from(frame.offset) + u32::from(frame.count)
            {
                return Err(Rejection(format!(
                    "{field} is not written by frame `{frame_name}`"
                )));
            }
            if targets.iter().any(|(other, _)| *other == index) {
                return Err(Rejection(format!("{field} is given twice")));
            }
            targets.push((index, target));
        }
        self.check_known_state(&targets, state)?;
        Ok(CommandPlan::from_fields(FieldPlan::new(
            Arc::clone(&self.inner),
            frame_name.to_string(),
            frame,
            targets,
        )))
    }

    /// Names of the profile's shared write frames (for group commands).
    pub fn write_frame_names(&self) -> Vec<&str> {
        self.inner
            .named_frames
            .iter()
            .map(|(name, _)| name.as_str())
            .collect()
    }
}
