//! A batch's settings as the coordinator takes them: its policies, and its dynamics, ranking and
//! generalization plans, each checked against the others. A client (`assay eval`) runs the same
//! check before it starts a process, so a plan the coordinator would refuse never costs a cluster
//! start.
//!
//! Owns: parsing and checking [`BatchSettings`]. Never reads task documents (the planner does).

use assay_model::dynamics::DynamicsConfig;
use assay_model::generalization::GeneralizationPlan;
use assay_model::policy::PolicySpec;
use assay_model::proxy::RankingPlan;

/// The settings of a batch as submitted: the policies by name, and the nested plans as the JSON
/// the client sent (empty: none).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BatchSettings {
    pub policies: Vec<String>,
    pub dynamics_budgets: Vec<u32>,
    pub dynamics_json: String,
    pub ranking_json: String,
    pub generalization_json: String,
}

/// The dynamics part of a batch: episode budgets and world-model settings.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DynamicsPlan {
    pub budgets: Vec<u32>,
    pub config: DynamicsConfig,
}

/// What is wrong with a batch's settings, by the part it concerns.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SettingsError {
    /// A policy name that does not parse (as `PolicySpec::parse` says).
    #[error("{0}")]
    Policy(String),
    #[error("dynamics budgets: {0}")]
    DynamicsBudgets(String),
    #[error("dynamics settings: {0}")]
    Dynamics(String),
    #[error("ranking settings: {0}")]
    Ranking(String),
    #[error("generalization settings: {0}")]
    Generalization(String),
}

/// The settings of a batch that passed [`check`].
#[derive(Debug)]
pub struct Settings {
    /// The policies (`oracle` when the request names none).
    pub policies: Vec<String>,
    pub dynamics: Option<DynamicsPlan>,
    pub ranking: Option<RankingPlan>,
    pub generalization: Option<GeneralizationPlan>,
}

/// The request's settings, or what is wrong with them (prefixed with the part it concerns).
pub fn check(req: &BatchSettings) -> Result<Settings, SettingsError> {
    let mut policies: Vec<String> = req.policies.clone();
    if policies.is_empty() {
        policies.push("oracle".into());
    }
    for p in &policies {
        PolicySpec::parse(p).map_err(SettingsError::Policy)?;
    }
    let dynamics = if req.dynamics_budgets.is_empty() {
        None
    } else {
        let config: DynamicsConfig = if req.dynamics_json.trim().is_empty() {
            DynamicsConfig::default()
        } else {
            serde_json::from_str(&req.dynamics_json)
                .map_err(|e| SettingsError::Dynamics(e.to_string()))?
        };
        let mut budgets = req.dynamics_budgets.clone();
        budgets.sort_unstable();
        budgets.dedup();
        if budgets.contains(&0) {
            return Err(SettingsError::DynamicsBudgets(
                "every budget must be at least 1 episode".to_owned(),
            ));
        }
        if config.image_size == 0
            || !config.image_size.is_multiple_of(16)
            || config.image_size > 256
        {
            return Err(SettingsError::Dynamics(format!(
                "image_size {} must be a multiple of 16 up to 256",
                config.image_size
            )));
        }
        Some(DynamicsPlan { budgets, config })
    };
    let ranking = if req.ranking_json.trim().is_empty() {
        None
    } else {
        let plan: RankingPlan = serde_json::from_str(&req.ranking_json)
            .map_err(|e| SettingsError::Ranking(e.to_string()))?;
        check_ranking(&plan, &policies, dynamics.as_ref()).map_err(SettingsError::Ranking)?;
        Some(plan)
    };
    let generalization = if req.generalization_json.trim().is_empty() {
        None
    } else {
        let plan: GeneralizationPlan = serde_json::from_str(&req.generalization_json)
            .map_err(|e| SettingsError::Generalization(e.to_string()))?;
        plan.validate().map_err(SettingsError::Generalization)?;
        if !policies.contains(&plan.train_policy) {
            return Err(SettingsError::Generalization(format!(
                "train_policy {:?} is not one of the batch's policies",
                plan.train_policy
            )));
        }
        let size = plan.config.image_size;
        let other = dynamics
            .as_ref()
            .map(|d| d.config.image_size)
            .or(ranking.as_ref().map(|r| r.config.world_model.image_size));
        if let Some(other) = other.filter(|o| *o != size) {
            return Err(SettingsError::Generalization(format!(
                "config.image_size {size} differs from the clips' {other}"
            )));
        }
        if let Some(r) = ranking.as_ref().filter(|r| !r.config.interface.is_empty()) {
            return Err(SettingsError::Generalization(format!(
                "its diffusion policies learn from clips at the original interface, and the \
                 ranking records them at {:?} (config.interface): run them as two batches",
                r.config.interface
            )));
        }
        Some(plan)
    };
    Ok(Settings {
        policies,
        dynamics,
        ranking,
        generalization,
    })
}

/// What the settings name that the batch lacks: a ranking or generalization group (`groups`)
/// that none of the batch's valid tasks (whose groups are `groups`) belongs to.
pub fn check_groups(settings: &Settings, groups: &[&str]) -> Result<(), SettingsError> {
    let named = [
        (
            SettingsError::Ranking as fn(String) -> SettingsError,
            settings.ranking.as_ref().map(|r| &r.groups),
        ),
        (
            SettingsError::Generalization,
            settings.generalization.as_ref().map(|g| &g.groups),
        ),
    ];
    for (part, named) in named {
        let Some(g) = named
            .into_iter()
            .flatten()
            .find(|g| !groups.contains(&g.as_str()))
        else {
            continue;
        };
        let mut have: Vec<&str> = groups.to_vec();
        have.sort_unstable();
        have.dedup();
        let reason = format!(
            "groups: no task of the batch is in group {g:?} (its groups: {})",
            have.join(", ")
        );
        return Err(part(reason));
    }
    Ok(())
}

/// Held-out seeds are held out only while no episode of the batch runs on them: a batch seed
/// inside the ladder's or the generalization's held-out range is refused, naming the seed, the
/// range and the setting that moves it. (`seeds` are the batch's, as the request lists them.)
pub fn check_seeds(settings: &Settings, seeds: &[u64]) -> Result<(), SettingsError> {
    let ladder = settings.ranking.as_ref().and_then(|r| r.ladder.as_ref());
    let ranges = [
        (
            SettingsError::Ranking as fn(String) -> SettingsError,
            "ladder.",
            ladder.map(|l| (l.held_out_seed_base, l.held_out_seeds)),
        ),
        (
            SettingsError::Generalization,
            "",
            settings
                .generalization
                .as_ref()
                .map(|g| (g.held_out_seed_base, g.held_out_seeds)),
        ),
    ];
    for (part, prefix, range) in ranges {
        let Some((base, n)) = range else { continue };
        let end = base.saturating_add(u64::from(n));
        if let Some(s) = seeds.iter().find(|&&s| (base..end).contains(&s)) {
            return Err(part(format!(
                "{prefix}held_out_seed_base: batch seed {s} is one of the held-out seeds \
                 {base}..{end}, so they would not be held out; move {prefix}held_out_seed_base \
                 past the batch's seeds"
            )));
        }
    }
    Ok(())
}

/// What a ranking plan asks that cannot work (the caller prefixes `ranking settings: `): proxy
/// settings, the clips' size, training policies that are not the batch's, a ranked policy that
/// is the scripted oracle (it reads the simulator's state, so it cannot act inside a world
/// model), a ladder that does not fit, and nothing to rank.
fn check_ranking(
    plan: &RankingPlan,
    policies: &[String],
    dynamics: Option<&DynamicsPlan>,
) -> Result<(), String> {
    plan.config.validate()?;
    let size = plan.config.world_model.image_size;
    if size == 0 || !size.is_multiple_of(16) || size > 256 {
        return Err(format!(
            "world_model.image_size {size} must be a multiple of 16 up to 256"
        ));
    }
    if let Some(d) = dynamics.filter(|d| d.config.image_size != size) {
        return Err(format!(
            "world_model.image_size {size} differs from the dynamics clips' {}",
            d.config.image_size
        ));
    }
    let at_interface = !plan.config.interface.is_empty();
    if at_interface && dynamics.is_some() {
        return Err(format!(
            "config.interface {:?}: the clips would be recorded at it, and dynamics diversity's \
             RSSM learns the original interface: run them as two batches",
            plan.config.interface
        ));
    }
    if at_interface && plan.ladder.is_some() {
        return Err(format!(
            "config.interface {:?}: the ladder's diffusion policies learn the original interface \
             only; rank policies of that interface (served, TorchScript) instead",
            plan.config.interface
        ));
    }
    if plan.train_policies.is_empty() {
        return Err("train_policies is empty (the world model trains on their episodes)".into());
    }
    if let Some(p) = plan.train_policies.iter().find(|p| !policies.contains(p)) {
        return Err(format!(
            "training policy {p:?} is not one of the batch's policies"
        ));
    }
    if let Some(p) = plan
        .config
        .world_model_policies
        .iter()
        .find(|p| !plan.train_policies.contains(p))
    {
        return Err(format!(
            "config.world_model_policies: {p:?} is not a training policy (the world model learns \
             from training policies' episodes only)"
        ));
    }
    let ranked: Vec<&String> = policies
        .iter()
        .filter(|p| !plan.train_policies.contains(p))
        .collect();
    for p in &ranked {
        if PolicySpec::parse(p).is_ok_and(|s| s.is_oracle()) {
            return Err(format!(
                "policy {p:?} is ranked but is the scripted oracle, which reads the simulator's state \
                 and cannot act inside a world model; name it in train_policies (it may train the \
                 world model) or rank a learned policy"
            ));
        }
    }
    if let Some(ladder) = &plan.ladder {
        ladder.validate()?;
        if !policies.contains(&ladder.train_policy) {
            return Err(format!(
                "ladder.train_policy {:?} is not one of the batch's policies (the ladder's \
                 policies imitate its episodes)",
                ladder.train_policy
            ));
        }
        if ladder.config.image_size != size {
            return Err(format!(
                "ladder.config.image_size {} differs from the clips' {size} (world_model.image_size)",
                ladder.config.image_size
            ));
        }
    }
    if plan.groups.iter().any(|g| g.trim().is_empty()) {
        return Err("groups: a group name is empty".into());
    }
    if ranked.is_empty() && plan.ladder.is_none() {
        return Err(
            "nothing to rank: every policy trains the proxy and there is no ladder of learned \
             policies"
                .into(),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use assay_model::proxy::{LadderPlan, ProxyConfig};

    fn plan(train: &[&str], ladder: Option<LadderPlan>) -> RankingPlan {
        RankingPlan {
            train_policies: train.iter().map(|p| p.to_string()).collect(),
            config: ProxyConfig::default(),
            ladder,
            groups: Vec::new(),
        }
    }

    fn names(p: &[&str]) -> Vec<String> {
        p.iter().map(|p| p.to_string()).collect()
    }

    #[test]
    fn a_ranked_oracle_is_refused_naming_it_and_why() {
        let policies = names(&["oracle", "oracle:noise=0.02", "diffusion:model=m"]);
        let e = check_ranking(&plan(&["oracle"], None), &policies, None).unwrap_err();
        assert!(
            e.contains("policy \"oracle:noise=0.02\" is ranked but is the scripted oracle")
                && e.contains("cannot act inside a world model")
                && e.contains("name it in train_policies"),
            "{e}"
        );
        // Training the world model is what an oracle may do; a learned policy is ranked.
        let ok = plan(&["oracle", "oracle:noise=0.02"], None);
        assert_eq!(check_ranking(&ok, &policies, None), Ok(()));
    }

    #[test]
    fn a_ladder_must_imitate_a_batch_policy_fit_the_clips_and_validate() {
        let policies = names(&["oracle", "oracle:noise=0.01"]);
        let train = ["oracle", "oracle:noise=0.01"];
        // Every policy trains the proxy: with a ladder there is still something to rank.
        assert_eq!(
            check_ranking(&plan(&train, Some(LadderPlan::default())), &policies, None),
            Ok(())
        );
        let e = check_ranking(&plan(&train, None), &policies, None).unwrap_err();
        assert!(e.starts_with("nothing to rank"), "{e}");
        let elsewhere = LadderPlan {
            train_policy: "oracle:noise=0.2".into(),
            ..LadderPlan::default()
        };
        let e = check_ranking(&plan(&train, Some(elsewhere)), &policies, None).unwrap_err();
        assert!(
            e.contains("ladder.train_policy \"oracle:noise=0.2\" is not one of the batch's"),
            "{e}"
        );
        let short = LadderPlan {
            episodes: vec![1],
            ..LadderPlan::default()
        };
        let e = check_ranking(&plan(&train, Some(short)), &policies, None).unwrap_err();
        assert!(e.starts_with("ladder.episodes"), "{e}");
        // A step is either ranked or training-only.
        let both = LadderPlan {
            checkpoints: vec![300, 1000],
            train_checkpoints: vec![500, 1000],
            ..LadderPlan::default()
        };
        let e = check_ranking(&plan(&train, Some(both)), &policies, None).unwrap_err();
        assert!(
            e.starts_with("ladder.train_checkpoints: step 1000 is also in ladder.checkpoints"),
            "{e}"
        );
        // A run is either ranked or training-only.
        let both = LadderPlan {
            episodes: vec![10, 40],
            train_episodes: vec![5, 40],
            ..LadderPlan::default()
        };
        let e = check_ranking(&plan(&train, Some(both)), &policies, None).unwrap_err();
        assert!(
            e.starts_with("ladder.train_episodes: 40 is also in ladder.episodes"),
            "{e}"
        );
        let mut other_size = LadderPlan::default();
        other_size.config.image_size = 32;
        let e = check_ranking(&plan(&train, Some(other_size)), &policies, None).unwrap_err();
        assert!(e.contains("ladder.config.image_size 32 differs"), "{e}");
        // The world model's policies are some of the training policies.
        let mut demonstrations = plan(&train, Some(LadderPlan::default()));
        demonstrations.config.world_model_policies = names(&["oracle"]);
        assert_eq!(check_ranking(&demonstrations, &policies, None), Ok(()));
        demonstrations.config.world_model_policies = names(&["random"]);
        let e = check_ranking(&demonstrations, &policies, None).unwrap_err();
        assert!(
            e.starts_with("config.world_model_policies: \"random\" is not a training policy"),
            "{e}"
        );
    }

    #[test]
    fn clips_at_a_policy_interface_are_refused_where_a_model_learns_only_the_original() {
        let policies = names(&["oracle", "torchscript:path=p.pt"]);
        let seven = "space=ee_delta,cameras=image:scene@32+wrist:wrist@32,state=ee_pos+gripper";
        let mut at = plan(&["oracle"], None);
        at.config.interface = seven.into();
        assert_eq!(check_ranking(&at, &policies, None), Ok(()));
        // Dynamics diversity's RSSM, in the same batch.
        let dynamics = DynamicsPlan {
            budgets: vec![4],
            config: DynamicsConfig::default(),
        };
        let e = check_ranking(&at, &policies, Some(&dynamics)).unwrap_err();
        assert!(
            e.contains("config.interface") && e.contains("two batches"),
            "{e}"
        );
        // A ladder of diffusion policies.
        let mut ladder = at.clone();
        ladder.ladder = Some(LadderPlan::default());
        let e = check_ranking(&ladder, &policies, None).unwrap_err();
        assert!(e.contains("ladder's diffusion policies"), "{e}");
        // The RSSM as the proxy's world model.
        let mut rssm = at.clone();
        rssm.config.model = assay_model::video::WorldModelKind::Rssm;
        let e = check_ranking(&rssm, &policies, None).unwrap_err();
        assert!(e.starts_with("interface: the RSSM"), "{e}");
        // An interface that does not read.
        let mut bad = at.clone();
        bad.config.interface = "space=joint_velocity".into();
        let e = check_ranking(&bad, &policies, None).unwrap_err();
        assert!(
            e.starts_with("interface: ") && e.contains("joint_velocity"),
            "{e}"
        );
    }

    #[test]
    fn a_named_group_the_batch_lacks_is_refused_naming_the_setting_and_the_groups() {
        let policies = names(&["oracle", "oracle:noise=0.01"]);
        let mut ranking = plan(
            &["oracle", "oracle:noise=0.01"],
            Some(LadderPlan::default()),
        );
        ranking.groups = names(&["placement"]);
        let settings = |ranking: RankingPlan, general: Vec<String>| Settings {
            policies: policies.clone(),
            dynamics: None,
            ranking: Some(ranking),
            generalization: Some(GeneralizationPlan {
                groups: general,
                ..GeneralizationPlan::default()
            }),
        };
        let batch = ["placement", "robomimic", "placement"];
        let ok = settings(ranking.clone(), names(&["robomimic"]));
        assert_eq!(check_groups(&ok, &batch), Ok(()));
        // Empty: every group.
        assert_eq!(
            check_groups(&settings(plan(&["oracle"], None), vec![]), &batch),
            Ok(())
        );
        let e = check_groups(&settings(ranking.clone(), names(&["robomimc"])), &batch)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "generalization settings: groups: no task of the batch is in group \"robomimc\" \
             (its groups: placement, robomimic)"
        );
        ranking.groups.push("stacking".into());
        let e = check_groups(&settings(ranking.clone(), vec![]), &batch)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(
                "ranking settings: groups: no task of the batch is in group \"stacking\""
            ),
            "{e}"
        );
        ranking.groups = names(&[" "]);
        let e = check_ranking(&ranking, &policies, None).unwrap_err();
        assert_eq!(e, "groups: a group name is empty");
    }

    #[test]
    fn a_batch_seed_among_the_held_out_seeds_is_refused_naming_it_and_the_range() {
        let policies = names(&["oracle", "oracle:noise=0.01"]);
        let ladder = LadderPlan {
            held_out_seeds: 20,
            held_out_seed_base: 1000,
            ..LadderPlan::default()
        };
        let settings = |ladder: LadderPlan, general: Option<GeneralizationPlan>| Settings {
            policies: policies.clone(),
            dynamics: None,
            ranking: Some(plan(&["oracle", "oracle:noise=0.01"], Some(ladder))),
            generalization: general,
        };
        let s = settings(ladder.clone(), None);
        assert_eq!(check_seeds(&s, &[0, 1, 999, 1020, 5000]), Ok(()));
        let e = check_seeds(&s, &[0, 1019]).unwrap_err().to_string();
        assert_eq!(
            e,
            "ranking settings: ladder.held_out_seed_base: batch seed 1019 is one of the held-out \
             seeds 1000..1020, so they would not be held out; move ladder.held_out_seed_base past \
             the batch's seeds"
        );
        // Without held-out seeds the ladder runs on the batch's own seeds: nothing to overlap.
        let batch_seeds = LadderPlan {
            held_out_seeds: 0,
            ..ladder.clone()
        };
        assert_eq!(check_seeds(&settings(batch_seeds, None), &[1000]), Ok(()));
        // The generalization's held-out seeds, likewise.
        let general = GeneralizationPlan {
            held_out_seed_base: 10,
            ..GeneralizationPlan::default()
        };
        let e = check_seeds(&settings(ladder, Some(general)), &[0, 12])
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(
                "generalization settings: held_out_seed_base: batch seed 12 is one of the \
                 held-out seeds 10..13"
            ),
            "{e}"
        );
    }
}
