# Run at every boot after boot.py (motor pins low); compiled into RAM, so kept short (docs/firmware.md, "Boot order").
try:
    import app
except Exception as e:
    print("rover not started:", repr(e))
else:
    if __name__ == "__main__":
        app.run()
