//! The judge's prompts: versioned template files in `workers/judge/prompts/`, written after
//! appendix A.1 of the generative-simulation evaluation paper. A prompt's id (`completion/v1`)
//! goes into every request (`X-Assay-Prompt-Version`), every cache key and every report; changing
//! a template's wording means a new file and a new version, never an edit in place.

use assay_model::quality::Item;

/// One prompt template.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Prompt {
    /// `<name>/<version>`, e.g. `scene-alignment/v1`.
    pub id: &'static str,
    /// The text, with `{description}` and (for caption prompts) `{captions}` to fill in.
    pub template: &'static str,
}

/// A VLM scores scene alignment from the 4 scene views.
pub const SCENE_ALIGNMENT: Prompt = Prompt {
    id: "scene-alignment/v1",
    template: include_str!("../prompts/scene-alignment.v1.txt"),
};

/// A VLM scores completion from the 8 keyframes.
pub const COMPLETION: Prompt = Prompt {
    id: "completion/v1",
    template: include_str!("../prompts/completion.v1.txt"),
};

/// A caption model describes one image (first stage of a caption + LLM judge).
pub const CAPTION: Prompt = Prompt {
    id: "caption/v1",
    template: include_str!("../prompts/caption.v1.txt"),
};

/// An LLM scores scene alignment from the captions of the 4 scene views.
pub const SCENE_ALIGNMENT_CAPTIONS: Prompt = Prompt {
    id: "scene-alignment-captions/v1",
    template: include_str!("../prompts/scene-alignment-captions.v1.txt"),
};

/// An LLM scores completion from the captions of the 8 keyframes.
pub const COMPLETION_CAPTIONS: Prompt = Prompt {
    id: "completion-captions/v1",
    template: include_str!("../prompts/completion-captions.v1.txt"),
};

/// The offline judge's rubrics are code, versioned like prompts.
pub const OFFLINE_SCENE_ALIGNMENT: &str = "offline-scene-alignment/v1";
pub const OFFLINE_COMPLETION: &str = "offline-completion/v1";

impl Prompt {
    /// The prompt for a VLM that sees the images of `item`.
    pub fn for_images(item: Item) -> Prompt {
        match item {
            Item::SceneAlignment => SCENE_ALIGNMENT,
            Item::Completion => COMPLETION,
        }
    }

    /// The prompt for an LLM that reads captions of the images of `item`.
    pub fn for_captions(item: Item) -> Prompt {
        match item {
            Item::SceneAlignment => SCENE_ALIGNMENT_CAPTIONS,
            Item::Completion => COMPLETION_CAPTIONS,
        }
    }

    /// The template with its fields filled in. The description is flattened onto one line so
    /// that it cannot add lines of its own (such as a `Score:` line) to the prompt's structure.
    pub fn render(&self, description: &str, captions: &[String]) -> String {
        let description = description.split_whitespace().collect::<Vec<_>>().join(" ");
        let captions = captions
            .iter()
            .enumerate()
            .map(|(i, c)| {
                format!(
                    "{}. {}",
                    i + 1,
                    c.split_whitespace().collect::<Vec<_>>().join(" ")
                )
            })
            .collect::<Vec<_>>()
            .join("\n");
        self.template
            .replace("{description}", &description)
            .replace("{captions}", &captions)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn templates_ask_for_the_answer_format_and_fill_in() {
        for p in [
            SCENE_ALIGNMENT,
            COMPLETION,
            SCENE_ALIGNMENT_CAPTIONS,
            COMPLETION_CAPTIONS,
        ] {
            assert!(p.template.trim_end().ends_with("Score: X"), "{}", p.id);
            assert!(p.template.contains("{description}"), "{}", p.id);
            let text = p.render("put the red\nblock  away", &["a red block".into()]);
            assert!(text.contains("put the red block away"), "{}", p.id);
            assert!(!text.contains('{'), "{}: unfilled field", p.id);
        }
        assert!(SCENE_ALIGNMENT.template.contains("4 images"));
        assert!(COMPLETION.template.contains("8 images"));
        assert!(SCENE_ALIGNMENT.template.contains("from 1 to 5"));
        assert!(COMPLETION.template.contains("from 0 to 10"));
    }
}
