# Driver: config.load on every file of a directory, one line each: the file's name and "ok" or the error. Runs
# unchanged in CPython and MicroPython, so the board and the flash tool refuse the same configs with the same words.
import os

import config


def main(directory):
    for name in sorted(os.listdir(directory)):
        try:
            config.load(directory + "/" + name)
            print(name, "ok")
        except ValueError as e:
            print(name, e)
