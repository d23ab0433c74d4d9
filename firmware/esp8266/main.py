# MicroPython runs this file at every boot, after boot.py (written by the flash tool) has driven the motor driver's
# PWM pins low. The board compiles it from source into RAM, so it stays this short; the program is app.py, which
# runs from flash (ROMFS) like every other module.
import app

if __name__ == "__main__":
    app.run()
