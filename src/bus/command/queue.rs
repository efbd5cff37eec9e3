//! A line's command queue. Commands travel boxed: the queue's buffer, allocated when the line
//! starts, then holds a pointer per place instead of a whole command, which a plant of a
//! thousand lines, each with a queue that is nearly always empty, feels.

use tokio::sync::mpsc;
use tokio::sync::mpsc::error::{SendError, TryRecvError, TrySendError};

use super::outcome::Command;

/// A queue of `capacity` commands for one line.
pub(crate) fn command_queue(capacity: usize) -> (CommandSender, CommandReceiver) {
    let (tx, rx) = mpsc::channel(capacity);
    (CommandSender(tx), CommandReceiver(rx))
}

/// The sending side of a line's command queue (the bridge's, or a test's).
#[derive(Debug, Clone)]
pub struct CommandSender(mpsc::Sender<Box<Command>>);

impl CommandSender {
    /// Waits for a place in the queue; the command comes back when the line has stopped.
    pub async fn send(&self, command: Command) -> Result<(), SendError<Command>> {
        self.0
            .send(Box::new(command))
            .await
            .map_err(|SendError(command)| SendError(*command))
    }

    /// Queues the command if there is a place now; it comes back (boxed, as it travels) when
    /// there is none or the line has stopped.
    pub fn try_send(&self, command: Command) -> Result<(), TrySendError<Box<Command>>> {
        self.0.try_send(Box::new(command))
    }
}

/// The line's side of its command queue.
#[derive(Debug)]
pub(crate) struct CommandReceiver(mpsc::Receiver<Box<Command>>);

impl CommandReceiver {
    /// The next command already queued, without waiting.
    pub(crate) fn try_recv(&mut self) -> Result<Command, TryRecvError> {
        self.0.try_recv().map(|command| *command)
    }

    /// Waits for the next command; `None` once every sender is gone and the queue is empty.
    pub(crate) async fn recv(&mut self) -> Option<Command> {
        self.0.recv().await.map(|command| *command)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rtu2mqtt_profile::registry::built_in;
    use rtu2mqtt_profile::DeviceState;

    fn command(id: u64) -> Command {
        let profile = built_in("ruiwan-dust-collector").unwrap();
        let plan = profile
            .plan_command("gear", "8", &DeviceState::new())
            .unwrap();
        Command {
            id,
            device: "dust".into(),
            plan,
        }
    }

    #[tokio::test]
    async fn commands_arrive_in_order_and_come_back_when_full_or_closed() {
        let (tx, mut rx) = command_queue(1);
        tx.send(command(1)).await.unwrap();
        match tx.try_send(command(2)) {
            Err(TrySendError::Full(back)) => assert_eq!(back.id, 2),
            other => panic!("expected a full queue, got {other:?}"),
        }
        assert_eq!(rx.try_recv().map(|c| c.id), Ok(1));
        assert!(matches!(rx.try_recv(), Err(TryRecvError::Empty)));
        tx.try_send(command(3)).unwrap();
        assert_eq!(rx.recv().await.map(|c| c.id), Some(3));
        drop(rx);
        match tx.send(command(4)).await {
            Err(SendError(back)) => assert_eq!(back.id, 4),
            Ok(()) => panic!("a stopped line took a command"),
        }
    }
}
