//! The optional Prometheus endpoint: a tiny HTTP/1.1 responder on tokio that answers
//! `GET /metrics` with the text rendered from the lines' statistics, 404 to other paths and
//! 405 to other methods. Off unless `gateway.metrics_listen` is set.
