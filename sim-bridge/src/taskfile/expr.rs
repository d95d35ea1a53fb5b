//! The expression language of task files: a small subset of Python's expression grammar, so
//! that a Control Suite task's `get_observation` and `get_reward` read almost as written in
//! dm_control (`(1 + xmat('torso', 'zz')) / 2`, `tolerance(height, bounds=(0.6, 2))`).
//!
//! Grammar, loosest binding first (Python's precedence and associativity):
//! ```text
//! or  ->  and ('or' and)*           and  ->  not ('and' not)*        not -> 'not' not | cmp
//! cmp ->  sum (('<'|'<='|'>'|'>='|'=='|'!=') sum)?
//! sum ->  term (('+'|'-') term)*    term ->  unary (('*'|'/') unary)*
//! unary -> '-' unary | '+' unary | power         power -> postfix ('**' unary)?
//! postfix -> atom ( '(' args ')' | '[' index ']' )*
//! atom -> number | 'string' | name | '(' expr ')' | '(' expr ',' ... ')' | '[' expr, ... ']'
//! index -> expr | expr? ':' expr?
//! ```
//! A statement (the initial state) is `target = expr` or a bare call.

use std::fmt;

/// Where in the source text a node starts (byte offset), for error messages.
pub type Pos = usize;

/// A parsed expression.
#[derive(Clone, Debug, PartialEq)]
pub enum Expr {
    /// A number literal.
    Num(f64, Pos),
    /// A string literal (a name in the model, a sigmoid, a component like `'zz'`).
    Str(String, Pos),
    /// `(a, b)` or `[a, b]`: a tuple or list of expressions.
    List(Vec<Expr>, Pos),
    /// An identifier: a defined quantity, a constant (`pi`, `inf`, `dt`) or a state field
    /// (`qpos`, `qvel`).
    Name(String, Pos),
    /// `f(args, key=value)`.
    Call {
        /// Function name.
        func: String,
        /// Positional arguments.
        args: Vec<Expr>,
        /// Keyword arguments, in order.
        kwargs: Vec<(String, Expr)>,
        /// Position of the name.
        pos: Pos,
    },
    /// `base[i]` or `base[a:b]`.
    Index {
        /// The indexed value.
        base: Box<Expr>,
        /// The index.
        index: Index,
        /// Position of `[`.
        pos: Pos,
    },
    /// `-x`, `not x`.
    Unary(UnOp, Box<Expr>, Pos),
    /// `a op b`.
    Binary(BinOp, Box<Expr>, Box<Expr>, Pos),
}

/// An index: one element or a slice (bounds may be negative, counted from the end).
#[derive(Clone, Debug, PartialEq)]
pub enum Index {
    /// `[i]`.
    At(Box<Expr>),
    /// `[a:b]`, either bound optional.
    Slice(Option<Box<Expr>>, Option<Box<Expr>>),
}

/// Unary operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UnOp {
    /// `-x`.
    Neg,
    /// `not x` (1 where x is 0, else 0).
    Not,
}

/// Binary operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(missing_docs)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
    Pow,
    Lt,
    Le,
    Gt,
    Ge,
    Eq,
    Ne,
    And,
    Or,
}

impl Expr {
    /// Where the expression starts.
    pub fn pos(&self) -> Pos {
        match self {
            Expr::Num(_, p)
            | Expr::Str(_, p)
            | Expr::List(_, p)
            | Expr::Name(_, p)
            | Expr::Unary(_, _, p)
            | Expr::Binary(_, _, _, p) => *p,
            Expr::Call { pos, .. } | Expr::Index { pos, .. } => *pos,
        }
    }
}

/// An initial-state statement.
#[derive(Clone, Debug, PartialEq)]
pub enum Statement {
    /// `target = value`.
    Assign {
        /// What is written (`qpos`, `qpos('slider')`, `qvel[1:]`, `time`).
        target: Expr,
        /// The value.
        value: Expr,
    },
    /// A bare call, e.g. `randomize_limited_and_rotational_joints()`.
    Call(Expr),
}

/// A syntax error at a byte offset.
#[derive(Clone, Debug, PartialEq)]
pub struct SyntaxError {
    /// Byte offset into the expression.
    pub pos: Pos,
    /// What was expected or found.
    pub message: String,
}

impl fmt::Display for SyntaxError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (at character {})", self.message, self.pos + 1)
    }
}

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Num(f64),
    Str(String),
    Name(String),
    Op(&'static str),
    End,
}

/// The longest operators first, so `**` is not read as two `*`.
const OPS: [&str; 18] = [
    "**", "<=", ">=", "==", "!=", "+", "-", "*", "/", "<", ">", "(", ")", "[", "]", ",", ":", "=",
];

fn lex(src: &str) -> Result<Vec<(Tok, Pos)>, SyntaxError> {
    let bytes = src.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i] as char;
        if c.is_ascii_whitespace() {
            i += 1;
        } else if c.is_ascii_digit()
            || (c == '.' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit))
        {
            let start = i;
            while i < bytes.len()
                && (bytes[i].is_ascii_digit() || bytes[i] == b'.' || bytes[i] == b'_')
            {
                i += 1;
            }
            if i < bytes.len() && (bytes[i] == b'e' || bytes[i] == b'E') {
                i += 1;
                if i < bytes.len() && (bytes[i] == b'+' || bytes[i] == b'-') {
                    i += 1;
                }
                while i < bytes.len() && bytes[i].is_ascii_digit() {
                    i += 1;
                }
            }
            let text: String = src[start..i].chars().filter(|&c| c != '_').collect();
            let v: f64 = text.parse().map_err(|_| SyntaxError {
                pos: start,
                message: format!("`{}` is not a number", &src[start..i]),
            })?;
            out.push((Tok::Num(v), start));
        } else if c.is_ascii_alphabetic() || c == '_' {
            let start = i;
            while i < bytes.len() && (bytes[i].is_ascii_alphanumeric() || bytes[i] == b'_') {
                i += 1;
            }
            out.push((Tok::Name(src[start..i].to_string()), start));
        } else if c == '\'' || c == '"' {
            let start = i;
            i += 1;
            let s = i;
            while i < bytes.len() && bytes[i] as char != c {
                i += 1;
            }
            if i == bytes.len() {
                return Err(SyntaxError {
                    pos: start,
                    message: "unterminated string".into(),
                });
            }
            out.push((Tok::Str(src[s..i].to_string()), start));
            i += 1;
        } else if let Some(op) = OPS.iter().find(|op| src[i..].starts_with(**op)) {
            out.push((Tok::Op(op), i));
            i += op.len();
        } else {
            let ch = src[i..].chars().next().unwrap_or(c);
            return Err(SyntaxError {
                pos: i,
                message: format!("unexpected character `{ch}`"),
            });
        }
    }
    out.push((Tok::End, src.len()));
    Ok(out)
}

/// A call's positional and keyword arguments.
type CallArgs = (Vec<Expr>, Vec<(String, Expr)>);

/// Expressions nest at most this deep: a file cannot overflow the parser's stack.
const MAX_DEPTH: usize = 64;

struct Parser {
    toks: Vec<(Tok, Pos)>,
    at: usize,
    depth: usize,
}

impl Parser {
    fn peek(&self) -> &Tok {
        &self.toks[self.at].0
    }

    fn pos(&self) -> Pos {
        self.toks[self.at].1
    }

    fn bump(&mut self) -> (Tok, Pos) {
        let t = self.toks[self.at].clone();
        if self.at + 1 < self.toks.len() {
            self.at += 1;
        }
        t
    }

    fn is_op(&self, op: &str) -> bool {
        matches!(self.peek(), Tok::Op(o) if *o == op)
    }

    fn is_word(&self, w: &str) -> bool {
        matches!(self.peek(), Tok::Name(n) if n == w)
    }

    fn err<T>(&self, message: String) -> Result<T, SyntaxError> {
        Err(SyntaxError {
            pos: self.pos(),
            message,
        })
    }

    fn found(&self) -> String {
        match self.peek() {
            Tok::Num(v) => format!("the number {v}"),
            Tok::Str(s) => format!("the string '{s}'"),
            Tok::Name(n) => format!("`{n}`"),
            Tok::Op(o) => format!("`{o}`"),
            Tok::End => "the end of the expression".into(),
        }
    }

    fn expect(&mut self, op: &str) -> Result<(), SyntaxError> {
        if self.is_op(op) {
            self.bump();
            Ok(())
        } else {
            self.err(format!("expected `{op}`, found {}", self.found()))
        }
    }

    fn expr(&mut self) -> Result<Expr, SyntaxError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return self.err(format!("expression nested deeper than {MAX_DEPTH} levels"));
        }
        let e = self.or();
        self.depth -= 1;
        e
    }

    fn or(&mut self) -> Result<Expr, SyntaxError> {
        let mut l = self.and()?;
        while self.is_word("or") {
            let p = self.bump().1;
            let r = self.and()?;
            l = Expr::Binary(BinOp::Or, Box::new(l), Box::new(r), p);
        }
        Ok(l)
    }

    fn and(&mut self) -> Result<Expr, SyntaxError> {
        let mut l = self.not()?;
        while self.is_word("and") {
            let p = self.bump().1;
            let r = self.not()?;
            l = Expr::Binary(BinOp::And, Box::new(l), Box::new(r), p);
        }
        Ok(l)
    }

    fn not(&mut self) -> Result<Expr, SyntaxError> {
        if self.is_word("not") {
            let p = self.bump().1;
            let e = self.nested(Self::not)?;
            return Ok(Expr::Unary(UnOp::Not, Box::new(e), p));
        }
        self.cmp()
    }

    fn cmp(&mut self) -> Result<Expr, SyntaxError> {
        let l = self.sum()?;
        let op = match self.peek() {
            Tok::Op("<") => BinOp::Lt,
            Tok::Op("<=") => BinOp::Le,
            Tok::Op(">") => BinOp::Gt,
            Tok::Op(">=") => BinOp::Ge,
            Tok::Op("==") => BinOp::Eq,
            Tok::Op("!=") => BinOp::Ne,
            _ => return Ok(l),
        };
        let p = self.bump().1;
        let r = self.sum()?;
        if matches!(self.peek(), Tok::Op("<" | "<=" | ">" | ">=" | "==" | "!=")) {
            return self
                .err("chained comparisons are not supported: write `a < b and b < c`".into());
        }
        Ok(Expr::Binary(op, Box::new(l), Box::new(r), p))
    }

    fn sum(&mut self) -> Result<Expr, SyntaxError> {
        let mut l = self.term()?;
        loop {
            let op = match self.peek() {
                Tok::Op("+") => BinOp::Add,
                Tok::Op("-") => BinOp::Sub,
                _ => return Ok(l),
            };
            let p = self.bump().1;
            let r = self.term()?;
            l = Expr::Binary(op, Box::new(l), Box::new(r), p);
        }
    }

    fn term(&mut self) -> Result<Expr, SyntaxError> {
        let mut l = self.unary()?;
        loop {
            let op = match self.peek() {
                Tok::Op("*") => BinOp::Mul,
                Tok::Op("/") => BinOp::Div,
                _ => return Ok(l),
            };
            let p = self.bump().1;
            let r = self.unary()?;
            l = Expr::Binary(op, Box::new(l), Box::new(r), p);
        }
    }

    /// Runs `f` one level deeper (unary chains such as `- - - x` count towards the limit).
    fn nested(
        &mut self,
        f: fn(&mut Self) -> Result<Expr, SyntaxError>,
    ) -> Result<Expr, SyntaxError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return self.err(format!("expression nested deeper than {MAX_DEPTH} levels"));
        }
        let e = f(self);
        self.depth -= 1;
        e
    }

    fn unary(&mut self) -> Result<Expr, SyntaxError> {
        if self.is_op("-") {
            let p = self.bump().1;
            let e = self.nested(Self::unary)?;
            // A negative literal stays a literal (`-0.1` is the number, as in Python's
            // constant folding), so `-1` and `- 1` both give -1.0 exactly.
            return Ok(match e {
                Expr::Num(v, _) => Expr::Num(-v, p),
                e => Expr::Unary(UnOp::Neg, Box::new(e), p),
            });
        }
        if self.is_op("+") {
            self.bump();
            return self.nested(Self::unary);
        }
        self.power()
    }

    fn power(&mut self) -> Result<Expr, SyntaxError> {
        let base = self.postfix()?;
        if self.is_op("**") {
            let p = self.bump().1;
            let e = self.nested(Self::unary)?;
            return Ok(Expr::Binary(BinOp::Pow, Box::new(base), Box::new(e), p));
        }
        Ok(base)
    }

    fn postfix(&mut self) -> Result<Expr, SyntaxError> {
        let mut e = self.atom()?;
        loop {
            if self.is_op("(") {
                let Expr::Name(func, pos) = e else {
                    return self.err("only a function name can be called".into());
                };
                self.bump();
                let (args, kwargs) = self.args()?;
                e = Expr::Call {
                    func,
                    args,
                    kwargs,
                    pos,
                };
            } else if self.is_op("[") {
                let pos = self.bump().1;
                let index = self.index()?;
                self.expect("]")?;
                e = Expr::Index {
                    base: Box::new(e),
                    index,
                    pos,
                };
            } else {
                return Ok(e);
            }
        }
    }

    fn args(&mut self) -> Result<CallArgs, SyntaxError> {
        let (mut args, mut kwargs) = (Vec::new(), Vec::<(String, Expr)>::new());
        while !self.is_op(")") {
            let keyword = match (self.peek(), self.toks.get(self.at + 1)) {
                (Tok::Name(n), Some((Tok::Op("="), _))) => Some(n.clone()),
                _ => None,
            };
            if let Some(k) = keyword {
                self.bump();
                self.bump();
                if kwargs.iter().any(|(n, _)| *n == k) {
                    return self.err(format!("keyword argument `{k}` given twice"));
                }
                kwargs.push((k, self.expr()?));
            } else if !kwargs.is_empty() {
                return self.err("a positional argument follows a keyword argument".into());
            } else {
                args.push(self.expr()?);
            }
            if !self.is_op(",") {
                break;
            }
            self.bump();
        }
        self.expect(")")?;
        Ok((args, kwargs))
    }

    fn index(&mut self) -> Result<Index, SyntaxError> {
        let lo = if self.is_op(":") {
            None
        } else {
            Some(Box::new(self.expr()?))
        };
        if !self.is_op(":") {
            return match lo {
                Some(e) => Ok(Index::At(e)),
                None => self.err("empty index".into()),
            };
        }
        self.bump();
        let hi = if self.is_op("]") {
            None
        } else {
            Some(Box::new(self.expr()?))
        };
        Ok(Index::Slice(lo, hi))
    }

    fn atom(&mut self) -> Result<Expr, SyntaxError> {
        let (t, p) = self.bump();
        match t {
            Tok::Num(v) => Ok(Expr::Num(v, p)),
            Tok::Str(s) => Ok(Expr::Str(s, p)),
            Tok::Name(n) if matches!(n.as_str(), "and" | "or" | "not") => Err(SyntaxError {
                pos: p,
                message: format!("expected a value, found `{n}`"),
            }),
            Tok::Name(n) => Ok(Expr::Name(n, p)),
            Tok::Op("(") => {
                let first = self.expr()?;
                if self.is_op(")") {
                    self.bump();
                    return Ok(first);
                }
                let mut items = vec![first];
                while self.is_op(",") {
                    self.bump();
                    if self.is_op(")") {
                        break;
                    }
                    items.push(self.expr()?);
                }
                self.expect(")")?;
                Ok(Expr::List(items, p))
            }
            Tok::Op("[") => {
                let mut items = Vec::new();
                while !self.is_op("]") {
                    items.push(self.expr()?);
                    if !self.is_op(",") {
                        break;
                    }
                    self.bump();
                }
                self.expect("]")?;
                Ok(Expr::List(items, p))
            }
            _ => {
                self.at -= usize::from(self.at > 0 && !matches!(t, Tok::End));
                self.err(format!("expected a value, found {}", self.found()))
            }
        }
    }

    fn finish(&self) -> Result<(), SyntaxError> {
        match self.peek() {
            Tok::End => Ok(()),
            _ => self.err(format!("unexpected {} after the expression", self.found())),
        }
    }
}

fn parser(src: &str) -> Result<Parser, SyntaxError> {
    Ok(Parser {
        toks: lex(src)?,
        at: 0,
        depth: 0,
    })
}

/// Parses one expression.
pub fn parse(src: &str) -> Result<Expr, SyntaxError> {
    let mut p = parser(src)?;
    let e = p.expr()?;
    p.finish()?;
    Ok(e)
}

/// Parses a statement: `target = expr` or a call.
pub fn parse_statement(src: &str) -> Result<Statement, SyntaxError> {
    // The one `=` that is not part of `==`, `<=`, `>=`, `!=` or a keyword argument (inside
    // parentheses) splits target from value.
    let bytes = src.as_bytes();
    let mut depth = 0i32;
    let mut split = None;
    let mut quote = None;
    for (i, &b) in bytes.iter().enumerate() {
        match (quote, b) {
            (Some(q), _) if b == q => quote = None,
            (Some(_), _) => {}
            (None, b'\'' | b'"') => quote = Some(b),
            (None, b'(' | b'[') => depth += 1,
            (None, b')' | b']') => depth -= 1,
            (None, b'=') if depth == 0 => {
                let prev = i.checked_sub(1).map(|j| bytes[j]);
                let next = bytes.get(i + 1).copied();
                if !matches!(prev, Some(b'=' | b'<' | b'>' | b'!')) && next != Some(b'=') {
                    split = Some(i);
                    break;
                }
            }
            _ => {}
        }
    }
    match split {
        Some(i) => {
            let target = parse(&src[..i])?;
            let value = parse(&src[i + 1..]).map_err(|e| SyntaxError {
                pos: e.pos + i + 1,
                message: e.message,
            })?;
            Ok(Statement::Assign { target, value })
        }
        None => match parse(src)? {
            e @ Expr::Call { .. } => Ok(Statement::Call(e)),
            e => Err(SyntaxError {
                pos: e.pos(),
                message: "a statement is `target = value` or a call such as `randomize_limited_and_rotational_joints()`".into(),
            }),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn n(v: f64) -> Box<Expr> {
        Box::new(Expr::Num(v, 0))
    }

    /// The tree with every position zeroed, for comparisons.
    fn strip(e: Expr) -> Expr {
        match e {
            Expr::Num(v, _) => Expr::Num(v, 0),
            Expr::Str(s, _) => Expr::Str(s, 0),
            Expr::Name(s, _) => Expr::Name(s, 0),
            Expr::List(v, _) => Expr::List(v.into_iter().map(strip).collect(), 0),
            Expr::Unary(o, e, _) => Expr::Unary(o, Box::new(strip(*e)), 0),
            Expr::Binary(o, l, r, _) => {
                Expr::Binary(o, Box::new(strip(*l)), Box::new(strip(*r)), 0)
            }
            Expr::Call {
                func, args, kwargs, ..
            } => Expr::Call {
                func,
                args: args.into_iter().map(strip).collect(),
                kwargs: kwargs.into_iter().map(|(k, v)| (k, strip(v))).collect(),
                pos: 0,
            },
            Expr::Index { base, index, .. } => Expr::Index {
                base: Box::new(strip(*base)),
                index: match index {
                    Index::At(e) => Index::At(Box::new(strip(*e))),
                    Index::Slice(a, b) => Index::Slice(
                        a.map(|e| Box::new(strip(*e))),
                        b.map(|e| Box::new(strip(*e))),
                    ),
                },
                pos: 0,
            },
        }
    }

    fn p(s: &str) -> Expr {
        strip(parse(s).unwrap())
    }

    #[test]
    fn precedence_and_associativity_follow_python() {
        use BinOp::*;
        let bin = |o, l, r| Expr::Binary(o, l, r, 0);
        // Left to right: a * b / c is (a * b) / c, as walker's `stand * (5 m + 1) / 6`.
        assert_eq!(
            p("1 * 2 / 3"),
            bin(Div, Box::new(bin(Mul, n(1.0), n(2.0))), n(3.0))
        );
        assert_eq!(
            p("1 - 2 - 3"),
            bin(Sub, Box::new(bin(Sub, n(1.0), n(2.0))), n(3.0))
        );
        // ** binds tighter than unary minus on its left and is right-associative.
        assert_eq!(
            p("-x ** 2"),
            Expr::Unary(
                UnOp::Neg,
                Box::new(bin(Pow, Box::new(Expr::Name("x".into(), 0)), n(2.0))),
                0
            )
        );
        assert_eq!(
            p("2 ** 3 ** 2"),
            bin(Pow, n(2.0), Box::new(bin(Pow, n(3.0), n(2.0))))
        );
        assert_eq!(
            p("1 < 2 or 3 > 4 and not 5"),
            bin(
                Or,
                Box::new(bin(Lt, n(1.0), n(2.0))),
                Box::new(bin(
                    And,
                    Box::new(bin(Gt, n(3.0), n(4.0))),
                    Box::new(Expr::Unary(UnOp::Not, n(5.0), 0))
                ))
            )
        );
        assert_eq!(p("-0.5"), Expr::Num(-0.5, 0));
        assert_eq!(p("1_000.5e-1"), Expr::Num(100.05, 0));
    }

    #[test]
    fn calls_indices_tuples_and_lists() {
        let e = p("tolerance(x[1:], bounds=(0.6, 2), sigmoid='linear')");
        let Expr::Call {
            func, args, kwargs, ..
        } = e
        else {
            panic!()
        };
        assert_eq!(func, "tolerance");
        assert_eq!(args.len(), 1);
        assert!(matches!(
            &args[0],
            Expr::Index {
                index: Index::Slice(Some(_), None),
                ..
            }
        ));
        assert_eq!(kwargs[0].0, "bounds");
        assert_eq!(
            kwargs[0].1,
            Expr::List(vec![Expr::Num(0.6, 0), Expr::Num(2.0, 0)], 0)
        );
        assert_eq!(kwargs[1].1, Expr::Str("linear".into(), 0));
        assert_eq!(
            p("xmat(['a', 'b'], 'xz')[:3]"),
            Expr::Index {
                base: Box::new(Expr::Call {
                    func: "xmat".into(),
                    args: vec![
                        Expr::List(vec![Expr::Str("a".into(), 0), Expr::Str("b".into(), 0)], 0),
                        Expr::Str("xz".into(), 0)
                    ],
                    kwargs: vec![],
                    pos: 0
                }),
                index: Index::Slice(None, Some(n(3.0))),
                pos: 0
            }
        );
    }

    #[test]
    fn statements_split_at_the_assignment() {
        let s = parse_statement("qpos('slider') = 0.01 * randn()").unwrap();
        assert!(matches!(s, Statement::Assign { .. }));
        let s = parse_statement("qpos[1:] = uniform(-0.034, 0.034, nv - 1)").unwrap();
        assert!(matches!(s, Statement::Assign { .. }));
        let s = parse_statement("randomize_limited_and_rotational_joints()").unwrap();
        assert!(matches!(s, Statement::Call(_)));
        // `==` and keyword arguments are not assignments.
        assert!(parse_statement("qpos == 1").is_err());
        assert!(matches!(
            parse_statement("step(n=200)").unwrap(),
            Statement::Call(_)
        ));
    }

    #[test]
    fn errors_say_where_and_what() {
        let e = parse("1 + * 2").unwrap_err();
        assert_eq!(e.pos, 4, "{e}");
        assert!(e.message.contains("expected a value"), "{e}");
        let e = parse("f(1").unwrap_err();
        assert!(e.message.contains("expected `)`"), "{e}");
        let e = parse("'abc").unwrap_err();
        assert!(e.message.contains("unterminated"), "{e}");
        let e = parse("1 2").unwrap_err();
        assert!(e.message.contains("after the expression"), "{e}");
        let e = parse("a < b < c").unwrap_err();
        assert!(e.message.contains("chained"), "{e}");
        let e = parse("1 $ 2").unwrap_err();
        assert!(e.message.contains("`$`"), "{e}");
        let deep = format!("{}1{}", "(".repeat(200), ")".repeat(200));
        assert!(parse(&deep).unwrap_err().message.contains("nested"));
        let minus = format!("{}1", "-(".repeat(100));
        assert!(parse(&minus).is_err());
        assert!(parse(&"- ".repeat(500)).is_err());
    }
}
