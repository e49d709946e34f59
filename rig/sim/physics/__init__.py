"""The simulated world: the test article, its joints and slips, the winch line and the bending fixture."""
