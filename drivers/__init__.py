"""Robot drivers behind one async protocol (docs/architecture.md, "Drivers"), managed by a kernel-owned lifecycle."""
