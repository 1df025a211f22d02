"""Robot drivers behind one async protocol (DESIGN.md §5), managed by a kernel-owned lifecycle."""
