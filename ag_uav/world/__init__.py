"""The world the drone flies in, built from the config before the flight: the field, the coverage
plan over it, the time-parameterised reference along the plan, the spray job's sorties, the
wind."""
