"""Hardware seams and the real drivers: servo bus on dynamixel-sdk, load cell on pyserial."""
