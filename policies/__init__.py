"""Active exploration for onlinemap: entropy rewards, policy iteration, exploration loops
(DESIGN.md section 4)."""
