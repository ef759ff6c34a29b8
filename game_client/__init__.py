"""The ninja-game client: gesture recogniser, game, renderer and the Zenoh app (``mocap-game``).

Pure cores (:mod:`~game_client.features`, :mod:`~game_client.detectors`, :mod:`~game_client.gestures`,
:mod:`~game_client.game`, :mod:`~game_client.round`) never touch a clock, a file or the network;
:mod:`~game_client.app` and :mod:`~game_client.cli` wire them to Zenoh, logs and frames.
"""

from .game import Game, GameConfig, PlayerInput
from .gestures import Gesture, GestureEvent, GestureRecognizer, RecognizerConfig, recognize
from .round import GameRound

__all__ = ["Game", "GameConfig", "GameRound", "Gesture", "GestureEvent", "GestureRecognizer", "PlayerInput",
           "RecognizerConfig", "recognize"]
