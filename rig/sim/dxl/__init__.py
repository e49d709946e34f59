"""The emulated Dynamixel bus: Protocol 2.0 framing, servos with their control tables, transports."""
