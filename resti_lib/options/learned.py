"""The learned blind attackers' settings and table, where the release and the notebooks import them; the
attackers themselves are the family module :mod:`resti_lib.options.attacks.learned`."""

from .attacks.learned import LearnedConfig, attack_table_with_learned, config_from, config_of, learned_picks

__all__ = ["LearnedConfig", "attack_table_with_learned", "config_from", "config_of", "learned_picks"]
