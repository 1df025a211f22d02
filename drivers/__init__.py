"""Robot drivers behind one async protocol, managed by a kernel-owned lifecycle
(docs/architecture.md, "Drivers")."""
