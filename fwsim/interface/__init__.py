"""The types both sides share: messages, frames and topics (the flight software imports only these)."""
