"""The loop: N missions in lockstep (physics, sensing, feedback, control, spray), and the missions
around it (simulate, simulate_many) and the step-response scenarios."""
