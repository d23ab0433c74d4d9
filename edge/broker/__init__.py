"""MQTT brokers for the appliance: the embedded amqtt broker, and the files of a Mosquitto deployment.

* :mod:`edge.broker.access`: who may do what (one table of rights for both brokers), Mosquitto's ``$7$`` hash;
* :mod:`edge.broker.credentials`: the clear logins (the state directory's, ``broker-config``'s);
* :mod:`edge.broker.gate` and :mod:`edge.broker.embedded`: the embedded broker, closed by default;
* :mod:`edge.broker.mosquitto` and :mod:`edge.broker.tls`: ``edge-ips broker-config`` (listeners, ACL, TLS).
"""

from edge.broker.access import Policy, acl_text, mosquitto_hash, verify_mosquitto_hash
from edge.broker.credentials import Credentials, Login, ensure_credentials, read_credentials, rover_login
from edge.broker.embedded import EmbeddedBroker
from edge.broker.gate import BrokerAccess
from edge.broker.mosquitto import BrokerFiles, write_mosquitto_config, write_password_file

__all__ = [
    "BrokerAccess",
    "BrokerFiles",
    "Credentials",
    "EmbeddedBroker",
    "Login",
    "Policy",
    "acl_text",
    "ensure_credentials",
    "mosquitto_hash",
    "read_credentials",
    "rover_login",
    "verify_mosquitto_hash",
    "write_mosquitto_config",
    "write_password_file",
]
